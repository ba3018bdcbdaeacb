"""aes-planner: camera viewpoint suggestion with a 3D aesthetic field.

The core (this package) is hardware-free. ``aes_planner.sim`` (the synthetic camera simulator)
and ``aes_planner.drivers`` (the Dynamixel pan-tilt bridge) sit beside it and depend on it,
never the other way round. Conventions (frames, angles, units) are stated once in
:mod:`aes_planner.geometry`.
"""

from aes_planner.runtime import tune_openmp

__version__ = "0.1.0"

tune_openmp()  # before anything imports torch (aes_planner.runtime says why)
