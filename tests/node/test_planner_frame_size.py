"""The planner keeps camera frames at the working size: a large frame is downscaled on input, not
rejected.
"""

import numpy as np


def test_the_planner_keeps_frames_at_the_working_size():
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.images import MAX_WORKING_SIDE_PX
    from aes_planner.messages import PosedFrame
    from aes_planner.node.planner import PlannerConfig, PlannerNode
    from aes_planner.platform import RigPlatformConfig
    from tests.node.nodekit import RIG, FakeTeacher, ScriptedProposer

    node = PlannerNode(
        PlannerConfig(platform=RigPlatformConfig(RIG), active=False), proposer=ScriptedProposer(), teacher=FakeTeacher()
    )
    k = Intrinsics(1000.0, 1000.0, 640.0, 480.0, 1280, 960)
    frame = PosedFrame(np.zeros((960, 1280, 3), np.uint8), k, ScriptedProposer().rig.forward(0.0, 0.0), 1.0)
    node.step({"camera/frame": [frame]}, 1.0)
    assert node.counters["frames_rejected"] == 0 and node._frame.width == MAX_WORKING_SIDE_PX
