"""The planner's step core, driven by hand (no bus): the active loop's states, its safety rules,
passive suggestions and the bounded frame store."""

import dataclasses
import math

import numpy as np
import pytest

from aes_planner.config import ConfigError
from aes_planner.messages import Candidate, PlannerRequest
from aes_planner.node.planner import Capture, PlannerConfig, PlannerNode
from aes_planner.platform import RigPlatformConfig

from .nodekit import RIG, FakeTeacher, ScriptedProposer, SimRig, frame_at


def make(proposer=None, **kw):
    kw.setdefault("polish_fine_captures", 0)  # the climbs' tests count their budget; the fine rounds have their own
    kw.setdefault("flank_hills", 0)  # and so do the flanks' rounds after the climbs
    cfg = PlannerConfig(platform=RigPlatformConfig(RIG), settle_s=0.0, **kw)
    return PlannerNode(cfg, proposer=proposer or ScriptedProposer(), teacher=FakeTeacher())


def drive(node, sim, steps=400, dt=0.05, t0=100.0):
    now = t0
    for _ in range(steps):
        out = node.step(sim.inputs(now), now)
        sim.apply(out)
        now += dt
        if node.finished:
            break
    return now


def test_active_loop_explores_moves_and_settles_on_the_best_capture():
    prop = ScriptedProposer()
    node = make(prop, explore_views=4, max_moves=3)
    sim = SimRig(prop)
    drive(node, sim)
    assert node.state == "done"
    kinds = [c.kind for c in node.captures]
    assert kinds[0] == "initial" and kinds.count("explore") == 4 and kinds[-1] == "settle"
    assert 1 <= node.moves <= 3
    best = max(node.captures[:-1], key=lambda c: c.score)
    assert node.captures[-1].pan_rad == pytest.approx(best.pan_rad)
    # the scripted optimum is reached: the move found the peak the exploration missed
    assert max(c.score for c in node.captures if c.kind == "move") > max(
        c.score for c in node.captures if c.kind == "explore"
    )
    lo, hi = math.radians(-90), math.radians(90)
    assert all(lo <= c.pan_rad <= hi and math.radians(-30) <= c.tilt_rad <= math.radians(30) for c in sim.commands)


def test_moves_are_bounded_by_the_budget():
    prop = ScriptedProposer()
    # a proposer that always promises more (and never the same view) would move forever
    counter = iter(range(1000))

    def always_better():
        i = next(counter)
        pan = -1.2 + 0.1 * (i % 24)
        return [Candidate(prop.rig.forward(pan, 0.1), 10.0 + i, 1.0, pan, 0.1)]

    prop.fixed = always_better
    node = make(prop, explore_views=2, max_moves=3)
    drive(node, SimRig(prop))
    assert node.state == "done" and node.moves == 3
    best = max(c.score for c in node.captures)
    assert node.outcome() == f"{node.node_id}: done after 3 moves; best captured score {best:.3f}"


def test_no_move_when_no_candidate_beats_the_best_capture():
    prop = ScriptedProposer()
    prop.fixed = lambda: [Candidate(prop.rig.forward(0.1, 0.0), -5.0, 1.0, 0.1, 0.0)]
    node = make(prop, explore_views=2, max_moves=5)
    drive(node, SimRig(prop))
    assert node.state == "done" and node.moves == 0
    assert " after 0 moves; " in node.outcome()


def test_out_of_range_candidates_are_refused_not_clamped_and_nonfinite_ones_never_commanded():
    prop = ScriptedProposer()
    calls = iter(range(1000))

    def wild():
        i = next(calls)
        c = Candidate(prop.rig.forward(0.0, 0.0), 9.0 + i, 1.0, 5.0 + i, -3.0)  # far outside the limits
        c.pan_rad = float("nan") if i == 0 else c.pan_rad  # a NaN sneaking past validation
        return [c]

    prop.fixed = wild
    node = make(prop, explore_views=1, max_moves=3)
    sim = SimRig(prop)
    drive(node, sim)
    for cmd in sim.commands:
        assert math.isfinite(cmd.pan_rad) and math.isfinite(cmd.tilt_rad)
        assert math.radians(-90) - 1e-9 <= cmd.pan_rad <= math.radians(90) + 1e-9
        assert math.radians(-30) - 1e-9 <= cmd.tilt_rad <= math.radians(30) + 1e-9
        assert cmd.pan_rad != pytest.approx(math.radians(90))  # no candidate was pulled onto the limit
    assert node.counters["commands_refused"] >= 1
    assert all(c.kind != "move" for c in node.captures)  # every wild candidate refused: no move


def test_hardware_fault_stops_commands_then_ends_failed_after_the_timeout():
    prop = ScriptedProposer()
    node = make(prop, explore_views=6, fault_timeout_s=1.0)
    sim = SimRig(prop)
    now = drive(node, sim, steps=5)
    sent = len(sim.commands)
    assert sent >= 1 and not node.finished
    sim.faults = ("pan: overload",)
    now = drive(node, sim, steps=60, t0=now)
    assert len(sim.commands) == sent  # nothing commanded while the gimbal is faulted
    assert node.state == "failed" and node.counters["faults"] == 1


def test_a_state_stamped_in_the_future_cannot_hide_a_later_fault():
    """One gimbal state from a clock far ahead was kept as the newest for good: every later state,
    a hardware fault's included, was older and ignored, and the loop went on as if arrived."""
    from .nodekit import state

    prop = ScriptedProposer()
    node = make(prop, explore_views=6, fault_timeout_s=1.0)
    sim = SimRig(prop)
    now = drive(node, sim, steps=5)
    node.step({"gimbal/state": [state(0.0, 0.0, stamp=now + 1e9)]}, now)
    node.step({"gimbal/state": ["not a state"]}, now)
    assert node.counters["states_rejected"] == 2
    sent = len(sim.commands)
    sim.faults = ("pan: overload",)
    drive(node, sim, steps=60, t0=now)
    assert len(sim.commands) == sent
    assert node.state == "failed" and node.counters["faults"] == 1


def test_a_frame_stamped_in_the_future_is_rejected_and_real_frames_still_count():
    prop = ScriptedProposer()
    node = make(prop, explore_views=3, max_moves=2)
    sim = SimRig(prop)
    now = drive(node, sim, steps=3)
    rejected = node.counters["frames_rejected"]
    ahead = frame_at(sim.kin, 0.0, 0.0, now + node.config.max_stamp_ahead_s + 1.0, 0.9, 999)
    node.step({"camera/frame": [ahead]}, now)
    assert node.counters["frames_rejected"] == rejected + 1
    drive(node, sim, t0=now)
    assert node.state == "done"
    assert all(c.stamp_s <= now + 600 for c in node.captures)  # never the future frame
    assert len({c.stamp_s for c in node.captures}) == len(node.captures)


def test_a_camera_that_falls_silent_ends_the_loop_after_the_move_timeout():
    prop = ScriptedProposer()
    node = make(prop, explore_views=4, move_timeout_s=2.0)
    sim = SimRig(prop)
    now = drive(node, sim, steps=4)
    captured = len(node.captures)
    assert captured >= 1 and not node.finished
    for _ in range(100):  # the gimbal still answers; the camera sends nothing
        out = node.step({"gimbal/state": sim.inputs(now)["gimbal/state"]}, now)
        sim.apply(out)
        now += 0.05
        if node.finished:
            break
    assert node.state == "failed" and node.counters["capture_timeouts"] == 1
    assert len(node.captures) in (captured, captured + 1)  # what it had is kept (the held frame may count)


def test_max_stamp_ahead_is_checked():
    with pytest.raises(ConfigError, match="max_stamp_ahead_s"):
        PlannerConfig(platform=RigPlatformConfig(RIG), max_stamp_ahead_s=-1.0)


def test_fault_that_clears_resumes_the_loop():
    prop = ScriptedProposer()
    node = make(prop, explore_views=3, max_moves=2, fault_timeout_s=30.0)
    sim = SimRig(prop)
    now = drive(node, sim, steps=10)
    sim.faults = ("tilt: overheating",)
    now = drive(node, sim, steps=20, t0=now)
    assert node.state not in ("done", "failed")
    sim.faults = ()
    drive(node, sim, t0=now)
    assert node.state == "done"


def test_frames_are_dropped_to_the_latest_and_counted(rig):
    prop = ScriptedProposer()
    node = make(prop, active=False, min_suggest_period_s=0.01)
    frames = [frame_at(rig, 0.1 * i, 0.0, 10.0 + i, seq=i) for i in range(5)]
    out = node.step({"camera/frame": frames}, 20.0)
    assert node.counters["frames_in"] == 5 and node.counters["frames_dropped"] == 4
    assert prop.frames[-1].sequence == 4 and len(prop.frames) == 1
    assert len(out["planner/suggestion"]) == 1


def test_passive_suggests_on_change_and_on_request(rig):
    prop = ScriptedProposer()
    node = make(prop, active=False, min_suggest_period_s=1.0)
    out = node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 1.0)]}, 1.0)
    assert len(out["planner/suggestion"]) == 1
    out = node.step({}, 1.1)  # nothing new: nothing published
    assert out["planner/suggestion"] == []
    out = node.step({"planner/request": [PlannerRequest("suggest")]}, 1.2)
    assert len(out["planner/suggestion"]) == 1  # the last one again, on request
    s = out["planner/suggestion"][0]
    assert s.mode == "rig" and all(np.isfinite(c.cam2world).all() for c in s.candidates)


def test_stale_and_resized_frames_are_rejected(rig):
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.messages import PosedFrame

    node = make(active=False)
    node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 5.0)]}, 5.0)
    node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 4.0)]}, 5.1)  # older than what it has
    k = Intrinsics.from_fov(16, 12, 60.0)
    big = PosedFrame(np.zeros((12, 16, 3), np.uint8), k, rig.forward(0.0, 0.0), 6.0)
    node.step({"camera/frame": [big]}, 6.0)
    assert node.counters["frames_rejected"] == 2


def test_diagnostics_report_counts_and_latency():
    prop = ScriptedProposer()
    node = make(prop, explore_views=2, max_moves=2, diagnostics_period_s=0.2)
    sim = SimRig(prop)
    drive(node, sim)
    d = node.diagnostics(1e3)
    assert d.state == "done" and d.counters["captures"] == len(node.captures)
    assert d.values["latency_p95_s"] >= d.values["latency_p50_s"] >= 0.0
    assert d.values["best_captured_score"] >= d.values["initial_score"]


def test_stop_request_settles_at_once():
    prop = ScriptedProposer()
    node = make(prop, explore_views=6)
    sim = SimRig(prop)
    now = drive(node, sim, steps=8)
    node.step({"planner/request": [PlannerRequest("stop")], **sim.inputs(now)}, now)
    drive(node, sim, t0=now + 0.05)
    assert node.state == "done" and node.captures[-1].kind == "settle"
    assert sum(c.kind == "explore" for c in node.captures) < 6


def test_config_errors_name_the_key():
    from aes_planner.config import ConfigError, from_dict

    with pytest.raises(ConfigError, match="max_movez"):
        from_dict(PlannerConfig, {"max_movez": 3})
    with pytest.raises(ConfigError, match="scorer"):
        PlannerConfig(scorer="gt")
    with pytest.raises(ConfigError, match="margin"):
        PlannerConfig(margin=float("nan"))
    for bad in (-1, 257, 1.5, True):
        with pytest.raises(ConfigError, match="threads"):
            PlannerConfig(threads=bad)
    for bad in (-1, 65, 2.0):
        with pytest.raises(ConfigError, match="polish_captures"):
            PlannerConfig(polish_captures=bad)
    for bad in (-1, 65, 2.0, True):
        with pytest.raises(ConfigError, match="polish_fine_captures"):
            PlannerConfig(polish_fine_captures=bad)
    for bad in (0.0, -1.0, float("nan"), 45.0):
        with pytest.raises(ConfigError, match="polish_step_deg"):
            PlannerConfig(polish_step_deg=bad)


def _one_candidate(prop, pan, tilt):
    prop.fixed = lambda: [Candidate(prop.rig.forward(pan, tilt), 10.0, 1.0, pan, tilt)]


def test_polish_climbs_from_the_move_towards_the_peak():
    prop = ScriptedProposer(peak=(0.6, 0.2))
    _one_candidate(prop, 0.6 + math.radians(6.0), 0.2 - math.radians(3.0))  # near the peak, not on it
    node = make(prop, explore_views=2, max_moves=1, polish_captures=8, polish_step_deg=2.5, polish_scales=1)
    sim = SimRig(prop)
    drive(node, sim)
    assert node.state == "done" and node.moves == 1
    kinds = [c.kind for c in node.captures]
    polish = [c for c in node.captures if c.kind == "polish"]
    assert 4 <= len(polish) <= 8 and kinds.index("polish") > kinds.index("move") and kinds[-1] == "settle"
    move = next(c for c in node.captures if c.kind == "move")
    final = node.captures[-1]
    assert final.score > move.score  # the climb found a better view than the field's
    assert math.hypot(final.pan_rad - 0.6, final.tilt_rad - 0.2) < math.hypot(move.pan_rad - 0.6, move.tilt_rad - 0.2)
    # every polish view is a step from an earlier capture, and none is captured twice
    step = math.radians(2.5)
    for c in polish:
        assert any(abs(math.hypot(c.pan_rad - o.pan_rad, c.tilt_rad - o.tilt_rad) - step) < 1e-6 for o in node.captures)
    poses = [(round(c.pan_rad, 6), round(c.tilt_rad, 6)) for c in node.captures[:-1]]
    assert len(poses) == len(set(poses))


def test_coarse_to_fine_polish_reaches_a_peak_a_fine_climb_cannot():
    """The field's move lands 15 deg off the peak: steps of 2.5 deg alone spend 8 captures and stop
    short; the coarse-to-fine search (10, 5, 2.5 deg) gets there with the same budget (12)."""
    peak = (0.6, 0.2)
    finals = {}
    for scales in (1, 3):
        prop = ScriptedProposer(peak=peak)
        _one_candidate(prop, peak[0] + math.radians(15.0), peak[1])
        node = make(prop, explore_views=2, max_moves=1, polish_captures=12, polish_step_deg=2.5, polish_scales=scales)
        drive(node, SimRig(prop))
        assert node.state == "done" and node.captures[-1].kind == "settle"
        assert sum(c.kind == "polish" for c in node.captures) <= 12
        finals[scales] = math.degrees(abs(node.captures[-1].pan_rad - peak[0]))
    assert finals[3] < 1.0 < finals[1]


def test_decisions_do_not_hinge_on_the_last_bits():
    """Two candidates whose hopes differ by 1e-9 either way are taken in the same order; a
    capture better by less than tie_tolerance does not displace the best one."""
    from aes_planner.node.captures import decision_order

    rig = ScriptedProposer().rig
    a = Candidate(rig.forward(0.3, 0.0), 0.5, 1.0, 0.3, 0.0)
    b = Candidate(rig.forward(-0.4, 0.1), 0.5, 1.0, -0.4, 0.1)
    for eps in (1e-9, -1e-9):
        assert decision_order(np.array([0.5 + eps, 0.5]), [a, b], 0.005) == [1, 0]  # pan -23 before +17
    assert decision_order(np.array([0.52, 0.5]), [a, b], 0.005) == [0, 1]  # a real difference wins
    node = make(ScriptedProposer(), tie_tolerance=0.002)
    node.captures = [Capture("initial", np.eye(4), 0.5, 0.0), Capture("explore", np.eye(4), 0.5015, 1.0)]
    assert node._best_capture() is node.captures[0]
    node.captures.append(Capture("move", np.eye(4), 0.51, 2.0))
    assert node._best_capture() is node.captures[2]


def test_polish_off_settles_after_the_last_move():
    prop = ScriptedProposer(peak=(0.6, 0.2))
    _one_candidate(prop, 0.65, 0.15)
    node = make(prop, explore_views=2, max_moves=1, polish_captures=0)
    drive(node, SimRig(prop))
    assert node.state == "done" and "polish" not in [c.kind for c in node.captures]


def test_polish_at_a_joint_limit_stays_inside_and_ends():
    prop = ScriptedProposer(peak=(2.0, 0.6))  # beyond pan 90 deg and tilt 30 deg: the corner is best
    corner = (math.radians(90.0), math.radians(30.0))
    _one_candidate(prop, *corner)
    node = make(prop, explore_views=2, max_moves=1, polish_captures=8, polish_step_deg=2.5, polish_scales=3)
    sim = SimRig(prop)
    drive(node, sim)
    assert node.state == "done"
    polish = [c for c in node.captures if c.kind == "polish"]
    assert len(polish) == 6  # at each of the 3 steps the two neighbours inside the limits; none better: ends
    lo, hi = math.radians(-90), math.radians(90)
    assert all(lo <= c.pan_rad <= hi and math.radians(-30) <= c.tilt_rad <= math.radians(30) for c in sim.commands)
    assert node.captures[-1].pan_rad == pytest.approx(corner[0])


def test_threads_knob_applies_in_the_stepping_thread():
    """``threads`` sets torch's count (process-wide) and numba's in the thread that steps: at
    once when the rasterizer's kernels are loaded, else when they load in that thread (numba is
    left untouched before, aes_planner.runtime says why), so the test holds whether an earlier
    test in the process loaded them or not."""
    import threading

    import numba
    import torch

    from aes_planner.gaussians import numba_backend

    before = torch.get_num_threads()
    seen = {}

    def step_once():
        node = make(threads=1)
        node.step({}, 100.0)
        seen["kernels"] = numba_backend.available()  # loads them here when no earlier test did
        seen["torch"], seen["numba"] = torch.get_num_threads(), numba.get_num_threads()

    try:
        t = threading.Thread(target=step_once)
        t.start()
        t.join()
        assert seen == {"kernels": True, "torch": 1, "numba": 1}
    finally:
        torch.set_num_threads(before)


class ContendedProposer(ScriptedProposer):
    """Takes a wall time set per thread count and little CPU, on clocks of its own (the node's
    ``wall_clock`` and ``cpu_clock``): a search beside a busy process, where two threads wait for
    each other and one thread is faster — whatever the machine running the test is doing."""

    def __init__(self, wall_s):
        super().__init__()
        self.wall_s = wall_s  # thread count -> seconds
        self.now_s = self.cpu_s = 0.0

    def attach(self, node):
        node.wall_clock, node.cpu_clock = (lambda: self.now_s), (lambda: self.cpu_s)
        return node

    def propose(self, platform, captured, top_k, keep_near=None, search=None):
        import torch

        took_s = self.wall_s[torch.get_num_threads()]
        self.now_s += took_s
        self.cpu_s += 0.1 * took_s  # an efficiency of 0.1 or less: the trigger's "little CPU"
        return super().propose(platform, captured, top_k, keep_near)


def test_threads_adapt_to_the_cpu_the_searches_get(rig):
    """With threads 0, searches that get little CPU set off a trial on one thread, kept because it
    is faster; a probe on all threads that wins brings them back when the neighbour leaves."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        prop = ContendedProposer({2: 0.06, 1: 0.02})
        node = prop.attach(make(prop, active=False, min_suggest_period_s=0.5))
        for i in range(4):  # 2 slow searches on two threads, then 2 faster ones on one
            node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 1.0 + i)]}, 1.0 + i)
        assert torch.get_num_threads() == 1 and node.governor.changes == 1 and not node.governor.trial
        d = node.diagnostics(10.0).values
        assert d["threads"] == 1.0 and d["thread_changes"] == 1.0 and d["cpu_efficiency"] < 0.65
        prop.wall_s[2] = 0.01  # the neighbour left: two threads are fastest again
        for i in range(node.governor.backoff):
            node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 10.0 + i)]}, 10.0 + i)
        assert torch.get_num_threads() == 2 and node.governor.threads == 2 and node.governor.changes == 2
        assert node.counters["suggestions"] == 4 + 8
    finally:
        torch.set_num_threads(before)


def test_fixed_threads_or_adapt_off_leave_the_count_alone():
    import torch

    before = torch.get_num_threads()
    try:
        for node in (make(threads=1), make(adapt_threads=False)):
            node.step({}, 1.0)
            assert node.governor is None
        node = make()
        node.step({}, 1.0)
        assert node.governor is not None and node.governor.max_threads == torch.get_num_threads()
    finally:
        torch.set_num_threads(before)


def test_start_readies_the_rasterizer_once_for_the_field_and_not_for_a_stand_in(monkeypatch):
    from aes_planner.gaussians import warmup

    calls = []
    monkeypatch.setattr(warmup, "warm_kernels", lambda: calls.append("raster") or 0.0)
    teacher = FakeTeacher()
    teacher.warm = lambda: calls.append("teacher") or 0.0  # Teacher.warm (the composition head's kernel)
    node = PlannerNode(PlannerConfig(platform=RigPlatformConfig(RIG)), teacher=teacher)  # the field's proposer
    node.start()
    node.start()
    assert calls == ["raster", "teacher"]  # compiled (or loaded) at start, not in the first plan
    make().start()  # a scripted proposer renders nothing
    assert calls == ["raster", "teacher"]


def test_step_takes_time_only_from_now(monkeypatch):
    """No wall clock inside the loop: every command and suggestion is stamped with a step's ``now``
    (the command chosen by a planning leaves in the next step, stamped with that step's clock),
    and the loop runs to its end with ``time.time`` unusable."""
    import time

    def no_wall_clock():
        raise AssertionError("the planner read the wall clock inside step")

    monkeypatch.setattr(time, "time", no_wall_clock)
    prop = ScriptedProposer()
    node = make(prop, explore_views=3, max_moves=2, polish_captures=2)
    sim, nows, suggestions = SimRig(prop), set(), []
    now = 100.0
    for _ in range(400):
        nows.add(now)
        out = node.step(sim.inputs(now), now)
        suggestions += out["planner/suggestion"]
        sim.apply(out)
        now += 0.05
        if node.finished:
            break
    assert node.state == "done" and node.moves >= 1 and suggestions
    assert {c.stamp_s for c in sim.commands} <= nows
    assert {s.stamp_s for s in suggestions} <= nows
    assert node.diagnostics(now).state == "done"  # the state word on the wire is the enum's value


class _TwoHills(ScriptedProposer):
    """A narrow hill of 0.75 at (0.6, 0.2) and a wide one of 1.0 at (-0.35, 0)."""

    def value(self, pan, tilt):
        a = 0.75 * math.exp(-((pan - 0.6) ** 2 + (tilt - 0.2) ** 2) / 0.01)
        b = math.exp(-((pan + 0.35) ** 2 + tilt**2) / 0.4)
        return float(max(a, b))


def test_polish_probes_a_second_hill_before_it_climbs():
    """The move lands on the narrow hill's top (0.75), the start view sits on the wide hill's flank
    (0.74): climbing around the best capture alone ends at 0.75; probing the runner-up's coarse
    neighbours first finds the higher hill."""
    finals = {}
    for starts in (1, 2):
        prop = _TwoHills()
        _one_candidate(prop, 0.6, 0.2)
        node = make(prop, explore_views=2, max_moves=1, polish_captures=16, polish_starts=starts, polish_hills=starts)
        drive(node, SimRig(prop))
        assert node.state == "done" and node.moves == 1
        finals[starts] = node.captures[-1].score
    assert finals[1] == pytest.approx(0.75, abs=0.01)
    assert finals[2] > 0.9


class _FarHill(ScriptedProposer):
    """A narrow hill of 0.75 at (0.6, 0.2) and a higher one of 1.0 at (-1.0, 0), far from the start
    and from the exploration's views."""

    def value(self, pan, tilt):
        a = 0.75 * math.exp(-((pan - 0.6) ** 2 + (tilt - 0.2) ** 2) / 0.01)
        b = math.exp(-((pan + 1.0) ** 2 + tilt**2) / 0.02)
        return float(max(a, b))


def test_polish_verifies_a_predicted_hill_the_moves_never_reached():
    """The field over-rates the narrow hill, so the one move goes there (0.75); the higher hill
    (1.0) is only predicted. Without verification the polish climbs the hills it captured and ends
    at 0.75; with it one capture of the higher hill's predicted top beats every capture and is
    the hill climbed first."""
    finals = {}
    for verify in (0, 2):
        prop = _FarHill()
        prop.fixed = lambda p=prop: [
            Candidate(p.rig.forward(0.6, 0.2), 10.0, 1.0, 0.6, 0.2),  # over-rated
            Candidate(p.rig.forward(-0.97, 0.03), p.value(-0.97, 0.03), 1.0, -0.97, 0.03),
        ]
        # short_hills 0: the over-rated move, once the verification beats it by more than the
        # start gap, would get probe rounds of its own on top of the budget (counted below)
        node = make(prop, explore_views=2, max_moves=1, polish_captures=16, verify_hills=verify, short_hills=0)
        drive(node, SimRig(prop), steps=800)
        assert node.state == "done" and node.moves == 1
        kinds = [c.kind for c in node.captures]
        assert kinds.count("verify") == (1 if verify else 0)
        assert kinds.count("polish") <= 16  # the verification comes on top of the polish budget
        finals[verify] = node.captures[-1].score
    assert finals[0] == pytest.approx(0.75, abs=0.01)
    assert finals[2] > 0.9


def test_a_coarse_polish_step_does_not_pull_the_climb_off_a_narrow_peak():
    """The move lands 1.7 deg beside a narrow peak (0.85, 2 deg wide); a neighbour 10 deg away on
    the flank of a broad, lower hill (0.725 at its top) scores 0.008 more than the centre. With
    tie_tolerance alone the centre moves there and the climb ends on the broad hill (dev
    wide_indoor_204 ``seed:1``: a 0.004 gain at 10 deg cost 0.1 of the oracle); with
    polish_coarse_gain the coarse step halves instead and the finer steps climb the narrow peak."""
    peak = (0.6, 0.2)
    sn, sb = math.radians(2.0), math.radians(12.0)
    broad_pan = peak[0] + math.radians(25.0)

    def value(pan, tilt):
        narrow = 0.85 * math.exp(-((pan - peak[0]) ** 2 + (tilt - peak[1]) ** 2) / (2 * sn**2))
        broad = 0.525 + 0.2 * math.exp(-((pan - broad_pan) ** 2 + (tilt - peak[1]) ** 2) / (2 * sb**2))
        return max(narrow, broad)

    finals = {}
    for gain in (0.0, 0.02):
        prop = ScriptedProposer(peak=peak)
        prop.value = value
        _one_candidate(prop, peak[0] - math.radians(1.7), peak[1])
        node = make(
            prop,
            explore_views=2,
            max_moves=1,
            polish_captures=24,
            polish_starts=1,
            polish_hills=1,
            verify_hills=0,
            polish_coarse_gain=gain,
        )
        drive(node, SimRig(prop), steps=1000)
        assert node.state == "done" and node.captures[-1].kind == "settle"
        finals[gain] = node.captures[-1].score
    assert finals[0.0] < 0.75 < 0.8 < finals[0.02]


class _ThreeHills(ScriptedProposer):
    """Two narrow hills whose tops the moves capture (0.75 at (0.6, 0.2), 0.74 at (-0.3, 0.1)) and
    a higher, broader one (1.0 at (0.0, -0.25)) that a move captured only on its flank (0.72)."""

    A, B, C = (0.6, 0.2), (-0.3, 0.1), (0.0, -0.25)
    SN, SC = math.radians(2.0), math.radians(7.4)

    def value(self, pan, tilt):
        def hill(top, at, s):
            return top * math.exp(-((pan - at[0]) ** 2 + (tilt - at[1]) ** 2) / (2 * s**2))

        return float(max(hill(0.75, self.A, self.SN), hill(0.74, self.B, self.SN), hill(1.0, self.C, self.SC)))


def _three_hills_loop(**kw) -> PlannerNode:
    """Three moves to _ThreeHills' two tops and the higher hill's flank (6 deg off), then the polish (48 captures)."""
    prop = _ThreeHills()
    flank = (prop.C[0] + math.radians(6.0), prop.C[1])
    prop.fixed = lambda p=prop, f=flank: [Candidate(p.rig.forward(*at), 10.0, 1.0, *at) for at in (p.A, p.B, f)]
    kw.setdefault("short_hills", 0)  # a flank move no climb starts from would get probe rounds of its own
    node = make(prop, explore_views=2, max_moves=3, polish_captures=48, verify_hills=0, **kw)
    drive(node, SimRig(prop), steps=2000)
    assert node.state == "done" and node.moves == 3
    moves = sorted(c.score for c in node.captures if c.kind == "move")
    assert moves[0] == pytest.approx(0.72, abs=0.01) and moves[-1] == pytest.approx(0.75, abs=0.01)
    assert sum(c.kind == "polish" for c in node.captures) <= 48
    return node


def test_the_polish_climbs_a_third_hill_the_moves_touched_on_its_flank():
    """Dev tabletop:202: the moves capture the tops of two lower hills and the oracle's hill only
    on its flank (0.68-0.72, third best); climbing the best two captured hills ends on a top of
    0.75, climbing the third too reaches the higher hill (the default ``polish_starts``; no hill probed
    beyond the climbs: ``polish_hills`` = ``polish_starts``)."""
    finals = {}
    for starts in (2, PlannerConfig().polish_starts):
        node = _three_hills_loop(polish_starts=starts, polish_hills=starts, spare_hills=0)
        finals[starts] = node.captures[-1].score
    assert finals[2] == pytest.approx(0.75, abs=0.01)
    assert finals[PlannerConfig().polish_starts] > 0.95


class _FourHills(_ThreeHills):
    """Three narrow hills whose tops the moves capture (0.75, 0.74, 0.73) and a higher, broader one
    (1.0) captured only on its flank (0.68): more hills within ``polish_start_gap`` than climbs."""

    D = (-0.5, -0.5)

    def value(self, pan, tilt):
        d = 0.73 * math.exp(-((pan - self.D[0]) ** 2 + (tilt - self.D[1]) ** 2) / (2 * self.SN**2))
        return float(max(super().value(pan, tilt), d))


def test_the_polish_probes_every_hill_before_it_chooses_which_to_climb():
    """Dev tabletop:202 `base`: the oracle's hill is captured fourth, on its flank (0.68), below
    three lower tops; three climbs of the best three captured never reach it. One coarse round on
    each of the four (``polish_hills``) finds the flank's uphill neighbour the best capture, and
    its hill is climbed."""
    finals = {}
    for hills in (3, PlannerConfig().polish_hills):
        prop = _FourHills()
        flank = (prop.C[0] + math.radians(6.5), prop.C[1])
        prop.fixed = lambda p=prop, f=flank: [
            Candidate(p.rig.forward(*at), 10.0, 1.0, *at) for at in (p.A, p.B, p.D, f)
        ]
        node = make(
            prop,
            explore_views=2,
            max_moves=4,
            polish_captures=48,
            polish_hills=hills,
            verify_hills=0,
            spare_hills=0,
            short_hills=0,  # the flank move (0.68) would get probe rounds of its own
        )
        drive(node, SimRig(prop), steps=2500)
        assert node.state == "done" and node.moves == 4
        moves = sorted(c.score for c in node.captures if c.kind == "move")
        assert moves[0] == pytest.approx(0.68, abs=0.01) and moves[-1] == pytest.approx(0.75, abs=0.01)
        assert sum(c.kind == "polish" for c in node.captures) <= 48
        finals[hills] = node.captures[-1].score
    assert finals[3] == pytest.approx(0.75, abs=0.01)
    assert finals[PlannerConfig().polish_hills] > 0.95


def test_fine_rounds_find_a_peak_between_the_finest_steps_only_where_the_camera_can_tell():
    """The move lands 3.75 deg off the peak: a climb in 2.5-deg steps stops 1.25 deg off it (its
    neighbours there are 1.25 and 3.75 off); the rounds at half that step reach the peak. A camera
    whose arrival tolerance exceeds the half step (a drone's 2 deg) cannot tell such a view from
    the one it is at: no fine rounds; nor with polish_captures 0 (settle at once)."""
    peak = (0.6, 0.2)
    off = {}
    for fine, tol in ((0, 0.6), (8, 0.6), (8, 1.5)):
        prop = ScriptedProposer(peak=peak)
        _one_candidate(prop, peak[0] + math.radians(3.75), peak[1])
        node = make(
            prop,
            explore_views=2,
            max_moves=1,
            polish_captures=8,
            polish_step_deg=2.5,
            polish_scales=1,
            polish_fine_captures=fine,
            arrival_tolerance_deg=tol,
        )
        drive(node, SimRig(prop))
        assert node.state == "done" and node.captures[-1].kind == "settle"
        polish = [c for c in node.captures if c.kind == "polish"]
        assert len(polish) <= 8 + fine
        off[fine, tol] = math.degrees(
            math.hypot(node.captures[-1].pan_rad - peak[0], node.captures[-1].tilt_rad - peak[1])
        )
    assert off[0, 0.6] == pytest.approx(1.25, abs=0.1)
    assert off[8, 0.6] < 0.1  # the half step reached it
    assert off[8, 1.5] == pytest.approx(1.25, abs=0.1)  # the gate: a tolerance wider than the half step
    prop = ScriptedProposer(peak=peak)
    _one_candidate(prop, peak[0] + math.radians(3.75), peak[1])
    node = make(prop, explore_views=2, max_moves=1, polish_captures=0, polish_fine_captures=8)
    drive(node, SimRig(prop))
    assert not any(c.kind == "polish" for c in node.captures)


class _TiedSteps(ScriptedProposer):
    """Dev wide_indoor_204: around the move (M), the finest climb round captures two views 2.5 deg
    either side in tilt that tie within a few thousandths (0.822 below, 0.816 above), and the
    peak (0.95, a spike 0.3 deg wide) lies 1.25 deg beyond the lower-scoring one."""

    M = (0.3, 0.0)
    SIGMA = math.radians(1.2)

    def value(self, pan, tilt):
        def bump(height, at, sigma):
            return height * math.exp(-((pan - at[0]) ** 2 + (tilt - at[1]) ** 2) / (2 * sigma**2))

        step = math.radians(2.5)
        below = bump(0.822, (self.M[0], self.M[1] - step), self.SIGMA)
        above = bump(0.816, (self.M[0], self.M[1] + step), self.SIGMA)
        spike = bump(0.95, (self.M[0], self.M[1] + 1.5 * step), math.radians(0.3))
        return float(max(below, above, spike))


def test_fine_rounds_go_on_around_a_near_best_capture_when_the_best_has_nothing_better():
    """With ``polish_fine_gap`` 0 the fine rounds circle only the best capture (0.822), whose
    neighbours are all lower, and the run settles there; with the default (0.01) they go on around
    the capture that tied it within 0.01 (0.816) and find the peak beside it (0.95). A capture
    further below the best than the gap gets no round (0.003: the two differ by 0.004 in 8-bit
    pixels)."""
    finals, fine = {}, {}
    for gap in (0.0, 0.003, None):
        prop = _TiedSteps()
        _one_candidate(prop, *prop.M)
        kw = {} if gap is None else {"polish_fine_gap": gap}
        node = make(
            prop,
            explore_views=2,
            max_moves=1,
            polish_captures=8,
            polish_step_deg=2.5,
            polish_scales=1,
            polish_fine_captures=PlannerConfig().polish_fine_captures,
            verify_hills=0,
            spare_hills=0,
            verify_unseen=False,
            **kw,
        )
        drive(node, SimRig(prop), steps=1500)
        assert node.state == "done" and node.moves == 1
        finals[gap] = node.captures[-1].score
        fine[gap] = sum(c.kind == "polish" for c in node.captures)
    assert PlannerConfig().polish_fine_gap == 0.01
    assert finals[0.0] == pytest.approx(0.822, abs=0.005) and finals[0.003] == pytest.approx(0.822, abs=0.005)
    assert finals[None] > 0.94
    assert fine[0.0] == fine[0.003] < fine[None] <= 8 + PlannerConfig().polish_fine_captures
    for bad in (-0.01, 0.2, float("nan")):
        with pytest.raises(ConfigError, match="polish_fine_gap"):
            PlannerConfig(polish_fine_gap=bad)


def test_spare_polish_captures_climb_a_hill_the_climbs_left_alone():
    """Dev tabletop:202 ``seed:2``: two climbs reached their finest steps on two lower tops (0.75,
    0.74) after 30 of the 48 polish captures, and the hill the oracle's view lies on, captured on its
    flank (0.72, within ``polish_start_gap`` of the best), was never climbed. With no spare hills
    the run ends at 0.75 with captures unspent; the spare captures climb the flank to the higher
    top. Nothing before the spare climb changes, so the run can only gain."""
    runs = {}
    for spare in (0, None):
        node = _three_hills_loop(polish_starts=2, polish_hills=2, spare_hills=spare)
        runs[spare] = (node.captures[-1].score, sum(c.kind == "polish" for c in node.captures))
    (lone, spent), (spared, _) = runs[0], runs[None]
    assert lone == pytest.approx(0.75, abs=0.01) and spent < 48  # the climbs left captures unspent
    assert spared > 0.95  # the rig's default (2 spare hills) climbs the flank


def test_spare_hills_default_is_the_platforms_and_is_checked():
    from aes_planner.node.motion import DroneMotion, RigMotion

    assert PlannerConfig().spare_hills is None
    assert RigMotion.spare_hills == 2 and DroneMotion.spare_hills == 2  # drones since session 29 (dev drones)
    for bad in (-1, 17, 1.5, True):
        with pytest.raises(ConfigError, match="spare_hills"):
            PlannerConfig(spare_hills=bad)


class _ShortMove(ScriptedProposer):
    """A narrow top of 0.75 a move captures (A) and a higher ridge (1.0 at C, 3 deg wide in tilt,
    broad in pan) whose one move landed 12 deg above it in tilt, where it scores ~0: the field
    found the hill, not its peak (dev tabletop:217: a move at tilt -27 scored 0.49 against a hope
    of 0.77, the 0.80 peak at tilt -12.5 on a ridge 5 deg wide)."""

    A, C = (0.6, 0.2), (-0.5, -0.25)
    OFF = math.radians(12.0)

    def value(self, pan, tilt):
        a = 0.75 * math.exp(-((pan - self.A[0]) ** 2 + (tilt - self.A[1]) ** 2) / (2 * math.radians(2.0) ** 2))
        c = math.exp(
            -(
                (pan - self.C[0]) ** 2 / (2 * math.radians(8.0) ** 2)
                + (tilt - self.C[1]) ** 2 / (2 * math.radians(3.0) ** 2)
            )
        )
        return float(max(a, c))


def test_a_move_that_fell_short_gets_probe_rounds_and_its_hill_is_climbed():
    """The move to the ridge's hill scores ~0, far below the best capture (0.75), so no climb
    starts there and the run ends on the lower top; with ``short_hills`` (a rig's default) a
    10-deg and a 5-deg round around that move (on top of the polish budget) find the ridge's
    flank within ``polish_start_gap`` of the best, and its climb reaches the ridge's top."""
    runs = {}
    for short in (0, None):
        prop = _ShortMove()
        flank = (prop.C[0], prop.C[1] + prop.OFF)
        prop.fixed = lambda p=prop, f=flank: [Candidate(p.rig.forward(*at), 10.0, 1.0, *at) for at in (p.A, f)]
        node = make(
            prop,
            explore_views=2,
            max_moves=2,
            polish_captures=48,
            verify_hills=0,
            verify_unseen=False,
            short_hills=short,
        )
        drive(node, SimRig(prop), steps=2500)
        assert node.state == "done" and node.moves == 2
        moves = sorted(c.score for c in node.captures if c.kind == "move")
        assert moves[0] < 0.05 and moves[-1] == pytest.approx(0.75, abs=0.01)
        runs[short] = (node.captures[-1].score, sum(c.kind == "polish" for c in node.captures))
    (lone, spent_lone), (probed, spent) = runs[0], runs[None]
    assert lone == pytest.approx(0.75, abs=0.01)
    assert probed > 0.95
    assert spent_lone <= 48 and spent <= 48 + 8  # the probes come on top of the budget, 8 at most a move


def test_short_hills_default_is_the_platforms_and_is_checked():
    from aes_planner.node.motion import DroneMotion, RigMotion

    assert PlannerConfig().short_hills is None
    assert RigMotion.short_hills == 2 and DroneMotion.short_hills == 0  # drones: not measured, unchanged
    for bad in (-1, 17, 1.5, True):
        with pytest.raises(ConfigError, match="short_hills"):
            PlannerConfig(short_hills=bad)


def test_the_loops_searches_on_a_rig_grid_the_joint_range_and_draw_nothing_at_random(rig):
    """``plan_grid_deg`` (a rig's default 4): every search of the active loop (the plannings and
    the hills' verification) asks for a pan x tilt grid at that spacing over the joint range and
    no random neighbours, so the search seed cannot change which hills it sees; 0 asks for the
    preset's stage 1; a passive suggestion is never changed."""
    from aes_planner.node.motion import DroneMotion, RigMotion

    assert PlannerConfig().plan_grid_deg is None
    assert RigMotion.plan_grid_deg == 4.0 and DroneMotion.plan_grid_deg == 0.0  # drones unchanged
    for step_deg, expected in ((None, 45 * 15), (2.0, 90 * 30), (0.0, None)):  # RIG: pan 180 deg, tilt 60 deg
        prop = ScriptedProposer()
        node = make(prop, explore_views=2, max_moves=2, polish_captures=8, plan_grid_deg=step_deg)
        drive(node, SimRig(prop), steps=800)
        assert node.state == "done" and prop.calls >= 2
        want = None if expected is None else {"grid_points": expected, "neighbours": 0, "top_k": 8}
        assert prop.searches == [want] * prop.calls
    prop = ScriptedProposer()
    node = make(prop, active=False, min_suggest_period_s=0.01)
    node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 1.0)]}, 1.0)
    assert prop.searches == [None]
    for bad in (-1.0, 0.2, 46.0, float("nan"), True, "4"):
        with pytest.raises(ConfigError, match="plan_grid_deg"):
            PlannerConfig(plan_grid_deg=bad)


class _UnseenHill(_FarHill):
    """_FarHill's search, which says its inputs cover 0.6 of the space and offers an exploratory
    candidate at the edge of what they saw, near the higher hill (1.0 at (-1.0, 0))."""

    EXPLORE = (-0.96, 0.03)

    def propose(self, platform, captured, top_k, keep_near=None, search=None):
        p = super().propose(platform, captured, top_k, keep_near)
        p.covered_fraction = 0.6
        p.explore = Candidate(self.rig.forward(*self.EXPLORE), 0.5, 0.0, *self.EXPLORE)
        return p


def test_the_loop_verifies_the_unseen_before_it_polishes():
    """Dev tabletop:213 ``base``: four moves went to predicted hills, none was left to explore,
    and the oracle's view lay 4.5 deg from the search's exploratory candidate, never captured
    (0.865 of the oracle). Without ``verify_unseen`` the run climbs the hill it has (0.75); with
    it (a rig's default) one capture of the exploratory candidate finds the higher hill, which
    beats every capture and is climbed first."""
    finals = {}
    for unseen in (False, None):
        prop = _UnseenHill()
        _one_candidate(prop, 0.6, 0.2)
        node = make(prop, explore_views=2, max_moves=1, polish_captures=16, verify_hills=2, verify_unseen=unseen)
        drive(node, SimRig(prop), steps=800)
        assert node.state == "done" and node.moves == 1
        assert [c.kind for c in node.captures].count("verify") == (0 if unseen is False else 1)
        finals[unseen] = node.captures[-1].score
    assert finals[False] == pytest.approx(0.75, abs=0.01)
    assert finals[None] > 0.95
    with pytest.raises(ConfigError, match="verify_unseen"):
        PlannerConfig(verify_unseen=1)


def test_the_planners_searches_keep_the_loops_steps_and_explore_pass(monkeypatch):
    """A one-shot ``balanced`` search takes 20 Adam steps and decodes 8 views in the explore pass;
    every search of the planner node (active or passive) keeps the loop's 25 and every partly
    covered view (``PLANNER_PRESETS``), unless ``PlannerConfig.search_steps`` says otherwise; a
    drone's loop keeps 25 steps, no screen and the whole explore pass (``DRONE_PLANNER_PRESETS``)."""
    import aes_planner.search as search
    from aes_planner.gaussians import warmup
    from aes_planner.messages import PosedFrame
    from aes_planner.node.proposer import FieldProposer
    from aes_planner.search import SearchConfig
    from aes_planner.search.pipeline import SearchResult

    from .nodekit import K

    one_shot = SearchConfig.preset("balanced")
    assert (one_shot.steps, one_shot.screen_keep, one_shot.explore_keep) == (20, 128, 8)
    loop = SearchConfig.preset("balanced", planner=True)
    assert (loop.steps, loop.screen_keep, loop.explore_keep) == (25, 128, 0)
    assert dataclasses.replace(loop, steps=20, explore_keep=8) == one_shot  # nothing else differs
    drone = SearchConfig.preset("balanced", mode="drone", planner=True)  # DRONE_PLANNER_PRESETS
    assert (drone.steps, drone.screen_keep, drone.explore_keep) == (25, 0, 0)
    assert SearchConfig.preset("balanced", mode="drone").screen_keep == 128  # a one-shot drone's
    assert SearchConfig.preset("fast", planner=True) == SearchConfig.preset("fast")

    seen = []
    monkeypatch.setattr(warmup, "warm_kernels", lambda: 0.0)
    monkeypatch.setattr(search, "build_search_scorer", lambda *a, **k: object())
    monkeypatch.setattr(search, "search_views", lambda s, i, p, cfg, **k: seen.append(cfg) or SearchResult([], p.kind))
    frame = PosedFrame(np.zeros((K.height, K.width, 3), np.uint8), K, np.eye(4), 0.0)
    rig = dict(platform=RigPlatformConfig(RIG))
    for config, want in (
        (PlannerConfig(**rig), 25),
        (PlannerConfig(**rig, active=False), 25),
        (PlannerConfig(**rig, search_steps=20), 20),
        (PlannerConfig(**rig, search_steps=0), 0),
    ):
        node = PlannerNode(config, proposer=FieldProposer("rgb", "balanced"), teacher=FakeTeacher())
        node.start()
        node.proposer.add_frame(frame, keep=True)
        node.proposer.propose(node.motion.bind(K), np.zeros((0, 4, 4)), 2)
        assert (seen[-1].steps, seen[-1].screen_keep, seen[-1].explore_keep) == (want, 128, 0)
    for bad in (-1, True, 2.5):
        with pytest.raises(ConfigError, match="search_steps"):
            PlannerConfig(search_steps=bad)


def test_hopes_a_thousandth_apart_across_a_quantum_edge_tie_within_the_margin():
    """``hope_tie_margin``: 0.752 / 0.753 against 0.751 / 0.752 (dev tabletop:217@drone under numba and
    torch) round to different quanta when one crosses 0.7525, and the first move changed with the
    backend; within the margin both orders are by where the candidates look, the same for both.
    The margin off, quanta alone; a real difference beyond it still wins."""
    from aes_planner.node.captures import decision_order

    rig = ScriptedProposer().rig
    a = Candidate(rig.forward(0.3, 0.0), 0.5, 1.0, 0.3, 0.0)
    b = Candidate(rig.forward(-0.4, 0.1), 0.5, 1.0, -0.4, 0.1)
    numba, torch_ = np.array([0.7515, 0.752]), np.array([0.753, 0.752])
    assert decision_order(numba, [a, b], 0.005) != decision_order(torch_, [a, b], 0.005)  # the edge decides
    assert decision_order(numba, [a, b], 0.005, 0.01) == decision_order(torch_, [a, b], 0.005, 0.01) == [1, 0]
    assert decision_order(np.array([0.78, 0.752]), [a, b], 0.005, 0.01) == [0, 1]
    assert decision_order(np.array([0.78, np.nan]), [a, b], 0.005, 0.01)[0] == 0
    with pytest.raises(ConfigError, match="hope_tie_margin"):
        PlannerConfig(hope_tie_margin=0.5)


class _VerifiedBeside(ScriptedProposer):
    """Dev gallery:228: a narrow hill of 0.75 at V (only predicted, then verified) and a higher,
    narrow one of 1.0 at M, 19.5 deg beside it in pan; the one move lands 3.3 deg off M (0.68)."""

    V = (-1.0, 0.0)
    M = (-1.0 + math.radians(19.5), 0.0)
    MOVE = (M[0], math.radians(3.3))

    def value(self, pan, tilt):
        def hill(top, at, s_deg):
            return top * math.exp(-((pan - at[0]) ** 2 + (tilt - at[1]) ** 2) / (2 * math.radians(s_deg) ** 2))

        return float(max(hill(0.75, self.V, 2.0), hill(1.0, self.M, 3.76)))


def test_a_move_beside_a_verified_best_view_is_a_hill_of_its_own():
    """The verification (0.75) is the best capture and the move (0.68, 3.3 deg off the higher
    peak) lies 19.8 deg from it: under two coarsest polish steps (20 deg) both count as one hill
    and only the verification's is climbed (0.75); from ``verify_apart_deg`` 15 the move is a
    hill of its own (the rig's default), and its climb reaches the higher peak."""
    finals = {}
    for apart in (20.0, None):  # None: the rig's default
        prop = _VerifiedBeside()
        prop.fixed = lambda p=prop: [
            Candidate(p.rig.forward(*p.MOVE), 10.0, 1.0, *p.MOVE),  # over-rated: the move
            Candidate(p.rig.forward(*p.V), p.value(*p.V), 1.0, *p.V),  # verified
        ]
        node = make(prop, explore_views=2, max_moves=1, polish_captures=48, verify_apart_deg=apart)
        drive(node, SimRig(prop), steps=2000)
        assert node.state == "done" and node.moves == 1
        kinds = [c.kind for c in node.captures]
        assert kinds.count("verify") == 1
        assert kinds.count("polish") <= 48
        (move,) = [c for c in node.captures if c.kind == "move"]
        assert move.score == pytest.approx(0.68, abs=0.01)
        finals[apart] = node.captures[-1].score
    assert finals[20.0] == pytest.approx(0.75, abs=0.01)
    assert finals[None] > 0.95


def test_verify_apart_deg_default_is_the_platforms_and_is_checked():
    from aes_planner.node.motion import DroneMotion, RigMotion

    assert PlannerConfig().verify_apart_deg is None
    assert RigMotion.verify_apart_deg == 15.0 and DroneMotion.verify_apart_deg is None  # drones: unchanged
    for bad in (0.0, -5.0, 91.0, float("nan"), True, "15"):
        with pytest.raises(ConfigError, match="verify_apart_deg"):
            PlannerConfig(verify_apart_deg=bad)


class _FlankPeak(ScriptedProposer):
    """Dev outdoor:242: the move lands on the top of a broad hill (0.75); the climb's 10-deg
    round puts a capture (0.66) 4 deg beside a narrow peak of 1.0 (2.5 deg wide), below the
    centre, and the climb stays on the broad top."""

    A = (math.radians(17.0), 0.0)
    B = (math.radians(27.0), math.radians(4.0))

    def value(self, pan, tilt):
        def hill(top, at, s_deg):
            return top * math.exp(-((pan - at[0]) ** 2 + (tilt - at[1]) ** 2) / (2 * math.radians(s_deg) ** 2))

        return float(max(hill(0.75, self.A, 20.0), hill(1.0, self.B, 2.5)))


def test_a_near_best_capture_beside_the_climbed_hill_gets_a_round_and_its_peak_is_climbed():
    """Without ``flank_hills`` the loop ends on the broad hill's top (0.75); with the rig's
    default the round's capture on the narrow peak's flank (0.66, within ``polish_start_gap``
    of the best) gets a 5-deg round, its probe beats it, and the climb from that probe reaches
    the peak, on top of the polish budget (<= 4 probes a flank, <= ``flank_captures`` climbing)."""
    runs = {}
    for flank in (0, None):  # None: the rig's default
        prop = _FlankPeak()
        prop.fixed = lambda p=prop: [Candidate(p.rig.forward(*p.A), 10.0, 1.0, *p.A)]
        node = make(
            prop,
            explore_views=2,
            max_moves=1,
            polish_captures=48,
            verify_hills=0,
            verify_unseen=False,
            flank_hills=flank,
        )
        drive(node, SimRig(prop), steps=3000)
        assert node.state == "done" and node.moves == 1
        (move,) = [c for c in node.captures if c.kind == "move"]
        assert move.score == pytest.approx(0.75, abs=0.01)
        runs[flank] = (node.captures[-1].score, sum(c.kind == "polish" for c in node.captures))
    (alone, spent_alone), (flanked, spent) = runs[0], runs[None]
    assert alone == pytest.approx(0.75, abs=0.01)
    assert flanked > 0.95
    assert spent_alone <= 48 and spent <= 48 + 6 * 4 + 16


def test_flank_hills_default_is_the_platforms_and_is_checked():
    from aes_planner.node.motion import DroneMotion, RigMotion

    assert PlannerConfig().flank_hills is None and PlannerConfig().flank_captures == 16
    assert RigMotion.flank_hills == 6 and DroneMotion.flank_hills == 6  # drones since session 29 (dev drones)
    for bad in (-1, 17, 1.5, True):
        with pytest.raises(ConfigError, match="flank_hills"):
            PlannerConfig(flank_hills=bad)
    for bad in (-1, 2.0, None, False):
        with pytest.raises(ConfigError, match="flank_captures"):
            PlannerConfig(flank_captures=bad)


class _BeyondTheFlank(ScriptedProposer):
    """Dev photo_ring_room: as :class:`_FlankPeak` (a broad 0.75 top, its round's capture on the
    flank of a narrow 0.8 peak B that the flanks' pass climbs), and a higher hill P (1.0) 14 deg
    beyond B behind a valley: no round was ever taken 10 deg out from B's top."""

    A = (math.radians(17.0), 0.0)
    B = (math.radians(27.0), math.radians(4.0))
    P = (math.radians(41.0), math.radians(4.0))

    def value(self, pan, tilt):
        def hill(top, at, s_deg):
            return top * math.exp(-((pan - at[0]) ** 2 + (tilt - at[1]) ** 2) / (2 * math.radians(s_deg) ** 2))

        return float(max(hill(0.75, self.A, 20.0), hill(0.8, self.B, 2.5), hill(1.0, self.P, 6.0)))


def test_the_top_a_flank_climb_reached_gets_a_coarse_round_and_the_flanks_pass_again():
    """Without ``flank_repeats`` (the default on both platforms) the flanks' climb tops B (0.8)
    and the loop settles there; with one repeat, a coarsest round around that top lands on P's flank (0.8, within
    ``polish_start_gap``), the flanks' pass again rounds it and climbs P (on top of the budget:
    4 coarse + 4 flank-round + ``flank_captures`` more captures at most)."""
    runs = {}
    for repeats in (0, 1):
        prop = _BeyondTheFlank()
        prop.fixed = lambda p=prop: [Candidate(p.rig.forward(*p.A), 10.0, 1.0, *p.A)]
        node = make(
            prop,
            explore_views=2,
            max_moves=1,
            polish_captures=48,
            verify_hills=0,
            verify_unseen=False,
            flank_hills=None,
            flank_repeats=repeats,
        )
        drive(node, SimRig(prop), steps=4000)
        assert node.state == "done" and node.moves == 1
        runs[repeats] = (node.captures[-1].score, sum(c.kind == "polish" for c in node.captures))
    (once, spent_once), (again, spent) = runs[0], runs[1]
    assert once == pytest.approx(0.8, abs=0.02)
    assert again > 0.95
    assert spent - spent_once <= 4 + 6 * 4 + 16


def test_flank_repeats_default_is_the_platforms_and_is_checked():
    from aes_planner.node.motion import DroneMotion, RigMotion

    assert PlannerConfig().flank_repeats is None
    # measured on dev rigs and not shipped (its ship rule's spread condition failed on
    # photo_ring_room, docs/benchmarks.md, session 28): opt-in on both platforms
    assert RigMotion.flank_repeats == 0 and DroneMotion.flank_repeats == 0
    for bad in (-1, 5, 1.5, True):
        with pytest.raises(ConfigError, match="flank_repeats"):
            PlannerConfig(flank_repeats=bad)
