"""The node types: the planner, the gimbal, the sim camera and drone, a real camera.

Each is a pure ``step(inputs, now) -> outputs`` core on the contract of
:class:`aes_planner.graph.base.Node`, registered by its ``type:`` word in
:data:`aes_planner.graph.base.NODE_TYPES`; :mod:`aes_planner.graph` runs them (one process or
one per node) and reads launch files.
"""
