"""Construction of each message type validates its fields and names them."""

import math

import numpy as np
import pytest

from aes_planner.geometry import view_to_cam2world
from aes_planner.messages import (
    Candidate,
    Diagnostics,
    GimbalCommand,
    GimbalState,
    MessageError,
    PlannerRequest,
    ViewSuggestion,
)

C2W = view_to_cam2world(np.array([0, 0, 1.0, 0.4, 0.2]))


def test_candidate_reads_view_from_pose():
    c = Candidate(C2W, 1.0)
    assert np.allclose(c.view, [0, 0, 1.0, 0.4, 0.2]) and math.isclose(c.yaw_rad, 0.4)
    assert np.allclose(c.position_m, [0, 0, 1.0])


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Candidate(np.diag([1.0, 1, 2, 1]), 1.0), "orthonormal"),
        (lambda: Candidate(C2W, math.nan), "score"),
        (lambda: Candidate(C2W, 1.0, coverage=1.5), "coverage"),
        (lambda: Candidate(C2W, 1.0, pan_rad=0.1), "together"),
        (lambda: Candidate(C2W, 1.0, terms={"a b": 1.0}), "key"),
        (lambda: Candidate(C2W, 1.0, terms={"a": math.inf}), "terms"),
        (lambda: ViewSuggestion(0.0, [Candidate(C2W, 1.0)] * 65), "cap"),
        (lambda: ViewSuggestion(0.0, ["x"]), "Candidate"),
        (lambda: ViewSuggestion(0.0, mode="orbit"), "mode"),
        (lambda: ViewSuggestion(0.0, frame_id="w\x1b[31m"), "control"),
        (lambda: GimbalCommand("move", math.nan, 0.0), "pan_rad"),
        (lambda: GimbalCommand("spin"), "kind"),
        (lambda: GimbalCommand(speed_rad_s=0.0), "speed"),
        (lambda: GimbalState(0, 0, 0, 0, moving=1), "moving"),
        (lambda: GimbalState(0, math.inf, 0, 0), "tilt_rad"),
        (lambda: GimbalState(0, 0, 0, 0, temperature_c=(1.0,)), "temperature"),
        (lambda: Diagnostics(0.0, "n", counters={"x": -1}), "counters"),
        (lambda: Diagnostics(0.0, "n", values={"x": math.nan}), "values"),
        (lambda: Diagnostics(0.0, "n", counters={str(i): 1 for i in range(200)}), "cap"),
        (lambda: PlannerRequest("dance"), "kind"),
        (lambda: PlannerRequest(max_candidates=100), "max_candidates"),
        (lambda: PlannerRequest(sequence=-1), "sequence"),
    ],
)
def test_bad_fields_are_named(make, match):
    with pytest.raises(MessageError, match=match):
        make()


def test_gimbal_state_converts_from_the_device_layer():
    from aes_planner import devices

    dev = devices.GimbalReading(0.1, 0.2, 0.3, 0.4, True, (30.0, 31.0), ("tilt: overload",), 5.0)
    back = GimbalState.from_device(dev, sequence=3)
    assert (back.pan_rad, back.tilt_rad, back.goal_pan_rad, back.goal_tilt_rad) == (0.1, 0.2, 0.3, 0.4)
    assert back.hardware_error == ("tilt: overload",) and back.status == "fault" and back.sequence == 3


@pytest.mark.parametrize("pitch", [-math.pi / 2, -0.7, 0.0, 0.3, math.pi / 2])
@pytest.mark.parametrize("yaw", [-3.0, -0.5, 0.0, 1.2, math.pi])
def test_candidate_view_matches_the_geometry_reference(yaw, pitch):
    from aes_planner.geometry import cam2world_to_view
    from aes_planner.messages.suggestion import view_of

    c2w = view_to_cam2world(np.array([1.0, -2.0, 0.5, yaw, pitch]))
    assert np.allclose(view_of(c2w), np.asarray(cam2world_to_view(c2w)), atol=1e-9)


def test_messages_import_without_torch():
    import subprocess
    import sys

    code = "import sys, aes_planner.messages, aes_planner.transport; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
