"""The simulated clock (aes_planner.graph.clock): lockstep semantics on toy nodes, its config, the
shared clock file the servo emulator reads, and that a node's wall-clock speed changes nothing."""

import random
import threading
import time
from dataclasses import dataclass

import pytest

from aes_planner.config import ConfigError
from aes_planner.graph.base import Node
from aes_planner.graph.clock import ACK_TOPIC, CLOCK_TOPIC, ClockConfig, ClockMaster, Lockstep, parse_clock
from aes_planner.graph.runner import Launch
from aes_planner.messages import Clock, ClockAck, Diagnostics
from aes_planner.transport import InProcessBus


@dataclass
class ToyConfig:
    period_s: float = 0.05
    max_delay_s: float = 0.0  # a random wall-clock pause in each step: a loaded machine
    seed: int = 0


class Ticker(Node):
    """Publishes a counter at its period."""

    config_class = ToyConfig
    outputs = {"toy/tick": (Diagnostics, False)}

    def __init__(self, config=None, node_id="ticker", context=None):
        super().__init__(config or ToyConfig(), node_id, context)
        self.n = 0
        self.rng = random.Random(self.config.seed)

    @property
    def period_s(self):
        return self.config.period_s

    def step(self, inputs, now):
        time.sleep(self.rng.uniform(0, self.config.max_delay_s))
        self.n += 1
        return {"toy/tick": [Diagnostics(now, self.node_id, counters={"n": self.n})]}


class Echo(Node):
    """Answers each tick with one echo; remembers what it got when."""

    config_class = ToyConfig
    inputs = {"toy/tick": (Diagnostics, 16)}
    outputs = {"toy/echo": (Diagnostics, False)}

    def __init__(self, config=None, node_id="echo", context=None):
        super().__init__(config or ToyConfig(period_s=10.0), node_id, context)
        self.seen: list[tuple[float, list[int]]] = []
        self.rng = random.Random(self.config.seed + 1)

    @property
    def period_s(self):
        return self.config.period_s

    def step(self, inputs, now):
        time.sleep(self.rng.uniform(0, self.config.max_delay_s))
        got = [m.counters["n"] for m in inputs["toy/tick"]]
        self.seen.append((round(now, 9), got))
        return {"toy/echo": [Diagnostics(now, self.node_id, counters={"n": n}) for n in got]}


class Listener(Node):
    """Records the echoes (and when they arrived) and finishes after ``stop_after`` of them."""

    config_class = ToyConfig
    inputs = {"toy/echo": (Diagnostics, 16)}
    outputs = {}
    stop_after = 12

    def __init__(self, config=None, node_id="listener", context=None):
        super().__init__(config or ToyConfig(period_s=10.0), node_id, context)
        self.seen: list[tuple[float, int, float]] = []

    @property
    def period_s(self):
        return self.config.period_s

    @property
    def finished(self):
        return len(self.seen) >= self.stop_after

    def step(self, inputs, now):
        self.seen += [(round(now, 9), m.counters["n"], m.stamp_s) for m in inputs["toy/echo"]]
        return {}


def run_toys(max_delay_s: float, step_s: float = 0.01):
    nodes = [
        (Listener(), {}),
        (Echo(ToyConfig(period_s=10.0, max_delay_s=max_delay_s, seed=3)), {}),
        (Ticker(ToyConfig(period_s=0.05, max_delay_s=max_delay_s, seed=5)), {}),
    ]
    launch = Launch(nodes, clock=ClockConfig("sim", step_s))
    with launch:
        assert launch.run(timeout_s=120)
    # the graph goes on until the launch notices the listener finished: compare up to there
    listener_seen = nodes[0][0].seen[: Listener.stop_after]
    end = listener_seen[-1][0]
    return [s for s in nodes[1][0].seen if s[0] <= end], listener_seen


def test_a_message_published_at_t_is_handled_at_the_next_tick_and_time_jumps_to_what_is_due():
    echo_seen, listener_seen = run_toys(0.0)
    # the ticker steps at 0, 0.05, 0.10, ...; the echo gets each tick one step (10 ms) later
    ticks = [(t, n) for t, n in echo_seen if n]
    assert ticks[:4] == [(0.01, [1]), (0.06, [2]), (0.11, [3]), (0.16, [4])]
    # its first step is due at 0 (nothing yet), then only when a message comes (period 10 s)
    assert echo_seen[0] == (0.0, [])
    # the listener gets echo n 10 ms after the echo published it, stamped with the echo's time
    assert listener_seen[:3] == [(0.02, 1, 0.01), (0.07, 2, 0.06), (0.12, 3, 0.11)]


def test_a_loaded_machine_changes_nothing_on_a_simulated_clock():
    """Random wall-clock pauses in every step (a busy machine, a slow node) leave the run as it
    was, to the message and the nanosecond."""
    assert run_toys(0.0) == run_toys(0.004)


def test_the_clock_resolution_is_the_delivery_delay():
    echo_seen, _ = run_toys(0.0, step_s=0.002)
    assert [(t, n) for t, n in echo_seen if n][:2] == [(0.002, [1]), (0.052, [2])]


def test_a_node_takes_only_what_was_published_before_its_tick():
    """Messages of the present tick that arrived already (another process was quicker) stay
    queued for the next tick; the node waits for the ones the clock says were sent."""
    bus = InProcessBus()
    sub = bus.subscribe("toy/tick", Diagnostics, depth=16)
    pub = bus.publisher("toy/tick", Diagnostics)
    clock_pub = bus.publisher(CLOCK_TOPIC, Clock, latched=True)
    ls = Lockstep(bus, "echo", {"toy/tick": sub}, {"toy/tick": "toy/tick"})
    stop = threading.Event()
    clock_pub.publish(Clock(0, 1, {}))
    assert ls.next_tick(stop).tick == 1
    pub.publish(Diagnostics(0.0, "ticker", counters={"n": 1}))  # tick 1's: arrives early
    assert ls.inputs(stop) == {"toy/tick": []}
    clock_pub.publish(Clock(10_000_000, 2, {"toy/tick": 2}))  # two were sent in tick 1
    assert ls.next_tick(stop).tick == 2
    got = []
    waiter = threading.Thread(target=lambda: got.append(ls.inputs(stop)))
    waiter.start()
    waiter.join(0.3)
    assert waiter.is_alive()  # one of the two has not arrived: it waits
    pub.publish(Diagnostics(0.0, "ticker", counters={"n": 2}))
    pub.publish(Diagnostics(0.01, "ticker", counters={"n": 3}))  # tick 2's, early
    waiter.join(10)
    assert [m.counters["n"] for m in got[0]["toy/tick"]] == [1, 2]
    assert [m.counters["n"] for m in sub.take()] == [3]
    bus.close()


def test_a_respawned_node_does_not_wait_for_what_was_sent_before_it_subscribed():
    """A node that joins a running graph (respawned) sees the latched tick N; tick N + 1 counts
    what the others sent during tick N, some of it before the node subscribed: it must go on with
    what reached it, not stop time (a supervisor test hung so once), and wait as usual after."""
    bus = InProcessBus()
    pub = bus.publisher("toy/tick", Diagnostics)
    clock_pub = bus.publisher(CLOCK_TOPIC, Clock, latched=True)
    clock_pub.publish(Clock(70_000_000, 7, {"toy/tick": 1}))  # time ran before this node came
    pub.publish(Diagnostics(0.07, "ticker", counters={"n": 1}))  # tick 7's, before it subscribed: lost
    sub = bus.subscribe("toy/tick", Diagnostics, depth=16)
    ls = Lockstep(bus, "echo", {"toy/tick": sub}, {"toy/tick": "toy/tick"})
    stop = threading.Event()
    assert ls.next_tick(stop).tick == 7
    assert ls.inputs(stop) == {"toy/tick": []}
    pub.publish(Diagnostics(0.07, "ticker", counters={"n": 2}))  # tick 7's, after it subscribed
    clock_pub.publish(Clock(80_000_000, 8, {"toy/tick": 2}))  # both counted
    assert ls.next_tick(stop).tick == 8
    got = []
    waiter = threading.Thread(target=lambda: got.append(ls.inputs(stop)))
    waiter.start()
    waiter.join(10)
    assert not waiter.is_alive() and [m.counters["n"] for m in got[0]["toy/tick"]] == [2]
    clock_pub.publish(Clock(90_000_000, 9, {"toy/tick": 1}))  # from here on it waits as any node
    assert ls.next_tick(stop).tick == 9
    got.clear()
    waiter = threading.Thread(target=lambda: got.append(ls.inputs(stop)))
    waiter.start()
    waiter.join(0.3)
    assert waiter.is_alive()
    pub.publish(Diagnostics(0.08, "ticker", counters={"n": 3}))
    waiter.join(10)
    assert [m.counters["n"] for m in got[0]["toy/tick"]] == [3]
    bus.close()


def test_the_master_waits_for_every_node_before_time_starts_and_between_ticks():
    bus = InProcessBus()
    clocks = bus.subscribe(CLOCK_TOPIC, Clock, depth=64)
    acks = bus.publisher(ACK_TOPIC, ClockAck)
    master = ClockMaster(bus, ["a", "b"], ClockConfig("sim", 0.01)).start()
    try:
        acks.publish(ClockAck("a", 0))
        assert not clocks.wait(0.3)  # b is not ready
        acks.publish(ClockAck("b", 0))
        assert clocks.wait(10) and clocks.take()[-1] == Clock(0, 1, {})
        acks.publish(ClockAck("a", 1, 50_000_000, {"x/y": 2}))
        assert not clocks.wait(0.3)  # b has not finished tick 1
        acks.publish(ClockAck("b", 1, 30_000_000))
        assert clocks.wait(10) and clocks.take()[-1] == Clock(10_000_000, 2, {"x/y": 2})  # delivery first
        acks.publish(ClockAck("a", 2, 50_000_000))
        acks.publish(ClockAck("b", 2, 33_000_000))
        assert clocks.wait(10) and clocks.take()[-1] == Clock(40_000_000, 3, {})  # 33 ms, on the 10 ms grid
        acks.publish(ClockAck("stranger", 3))  # not a node of this graph: ignored
        assert not clocks.wait(0.2)
    finally:
        master.stop()
        bus.close()


@pytest.mark.parametrize(
    "value, match",
    [
        ("solar", "clock: expected one of sim, wall"),
        ({"source": "sim", "step_s": 0}, "clock.step_s"),
        ({"source": "sim", "step_s": float("nan")}, "clock.step_s"),
        ({"source": "sim", "tick": 1}, "clock.tick"),
        (3, "clock: expected sim, wall or a mapping"),
    ],
)
def test_bad_clock_settings_are_errors_naming_the_key(value, match):
    with pytest.raises(ConfigError, match=match):
        parse_clock(value)


def test_launch_files_say_their_clock_and_real_devices_refuse_a_simulated_one():
    from aes_planner.graph import load_launch

    assert load_launch("sim_closed_loop").clock == ClockConfig("sim")
    assert load_launch("sim_closed_loop", ["clock=wall"]).clock.source == "wall"
    assert load_launch("pan_tilt_rig").clock.source == "wall"
    assert load_launch("drone", ["drone.type=sim", "clock={source: sim, step_s: 0.005}"]).clock.step_ns == 5_000_000
    with pytest.raises(ConfigError, match="nodes\\[0\\]: 'gimbal' drives a real gimbal"):
        load_launch("pan_tilt_rig", ["clock=sim"])
    with pytest.raises(ConfigError, match="'drone' runs elsewhere, in real time"):
        load_launch("drone", ["clock=sim"])


def test_the_servo_emulator_reads_the_time_the_gimbal_node_sets():
    from aes_planner.drivers.emulator import FileClock

    owner = FileClock.create(1.5)
    try:
        reader = FileClock(owner.path)
        assert reader() == 1.5
        owner.set(12.25)
        assert reader() == 12.25
        reader.close()
    finally:
        owner.close()
    assert not owner.path.exists()
