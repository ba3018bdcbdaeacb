"""``aes-planner demo``: the main job of ``make demo``.

Until the simulator lands, it walks the default pan-tilt rig over its joint range and prints the
camera pose at each setting (forward kinematics, then the inverse back to the joints).
"""

from __future__ import annotations

import argparse
import math


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the demonstration (make demo)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from aes_planner.geometry import PanTilt

    rig = PanTilt()
    print("pan_deg tilt_deg   x_m     y_m     z_m   yaw_deg pitch_deg  inverse(pan,tilt)_deg")
    for pan, tilt in rig.joint_grid(3, 3):
        view = rig.view_of(pan, tilt)
        sol = rig.inverse_direction(rig.forward(pan, tilt)[:3, 2], pan)
        print(
            f"{math.degrees(pan):7.1f} {math.degrees(tilt):8.1f} "
            f"{view[0]:7.3f} {view[1]:7.3f} {view[2]:7.3f} {math.degrees(view[3]):8.1f} {math.degrees(view[4]):8.1f}"
            f"   ({math.degrees(sol.pan_rad):.1f}, {math.degrees(sol.tilt_rad):.1f})"
        )
    return 0
