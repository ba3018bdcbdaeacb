"""One valid sample of every message type: for round trips, fuzzing, bus tests and bad-input sweeps.

Every registered type has an entry (a test checks it), so a sweep over ``sample_messages()`` covers
every message type."""

from __future__ import annotations

import numpy as np

from aes_planner.geometry import Intrinsics, view_to_cam2world
from aes_planner.messages import (
    Candidate,
    Clock,
    ClockAck,
    Diagnostics,
    DroneState,
    GimbalCommand,
    GimbalState,
    PlannerRequest,
    PosedFrame,
    ViewSuggestion,
)
from aes_planner.messages.diagnostics import FramingRegion


def sample_messages() -> dict:
    """``{type name: a valid message}``, deterministic."""
    rng = np.random.default_rng(1)
    c2w = view_to_cam2world(np.array([0.5, -0.2, 1.2, 0.3, -0.1]))
    frame = PosedFrame(
        rng.integers(0, 256, (6, 8, 3), dtype=np.uint8),
        Intrinsics.from_fov(8, 6, 60.0),
        c2w,
        stamp_s=2.5,
        depth_m=rng.uniform(0, 3, (6, 8)).astype(np.float32),
        frame_id="cam0",
        sequence=7,
        pan_rad=0.3,
        tilt_rad=-0.1,
    )
    suggestion = ViewSuggestion(
        3.0,
        [
            Candidate(c2w, 0.8, 0.95, 0.3, -0.1, {"thirds": 0.4, "balance": -0.1}),
            Candidate(view_to_cam2world(np.array([0, 0, 1.0, -1.0, 0.2])), 0.5, 0.5),
        ],
        field_version=4,
        sequence=2,
        mode="rig",
        covered_fraction=0.625,
        explore=Candidate(view_to_cam2world(np.array([0, 0, 1.0, 2.5, 0.1])), 0.3, 0.2, 2.5, 0.1),
    )
    return {
        "PosedFrame": frame,
        "ViewSuggestion": suggestion,
        "GimbalCommand": GimbalCommand("move", 0.25, -0.5, 1.5, stamp_s=1.0, sequence=9),
        "GimbalState": GimbalState(0.1, 0.2, 0.3, 0.4, True, (35.0, 36.5), ("pan: overload",), 4.0, 11, "fault"),
        "Diagnostics": Diagnostics(5.0, "planner", "exploring", {"frames_in": 10}, {"latency_p50_s": 0.12}),
        "PlannerRequest": PlannerRequest(
            "suggest", 3, 6.0, 1, set_framing=True, keep=[FramingRegion("00003.png", 21.0, 0.0, 61.0, 36.0)]
        ),
        "Clock": Clock(1_250_000_000, 126, {"gimbal/state": 1, "camera/frame": 1}),
        "ClockAck": ClockAck("camera", 126, 1_320_000_000, {"camera/frame": 1}),
        "DroneState": DroneState(
            7.0,
            c2w,
            [1.0, 2.0, 3.0],
            [0.1, 0.0, -0.2],
            [1.0, 0.0, 0.0, 0.0],
            -0.2,
            0.1,
            "OFFBOARD",
            True,
            1,
            "ok",
            "flying",
            3,
        ),
    }
