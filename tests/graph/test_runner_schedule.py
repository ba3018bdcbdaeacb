"""The node loop's schedule: inputs wake a step at once and never push the periodic step away.

Issue 42: each step woken by an input moved the periodic deadline a period further, so a node fed
faster than its period (the ROS 2 bridge) ran far ahead of the clock; an input that arrived during
a step then waited until that deadline (10-30 s in the closed loop, with every input queued)."""

import threading

from aes_planner.graph.base import Node
from aes_planner.graph.runner import NodeRunner
from aes_planner.messages import GimbalState
from aes_planner.transport import InProcessBus
from tests.helpers import wait_for


class _Counter(Node):
    config_class = dict
    inputs = {"t/in": (GimbalState, 100)}
    outputs = {}

    def __init__(self, period_s: float):
        super().__init__({}, "counter")
        self._period_s = period_s
        self.seen: list[int] = []
        self.steps = 0
        self.hold = threading.Event()  # a step that gets sequence 1000 waits for it
        self.holding = threading.Event()

    @property
    def period_s(self) -> float:
        return self._period_s

    def step(self, inputs, now):
        self.steps += 1
        for msg in inputs.get("t/in", []):
            self.seen.append(msg.sequence)
            if msg.sequence == 1000:
                self.holding.set()
                self.hold.wait(30)
        return {}


def _run(node):
    bus = InProcessBus()
    runner = NodeRunner(node, bus)
    runner.open()
    runner.start_thread()
    return bus, runner


def test_an_input_that_arrives_during_a_step_is_taken_at_once_after_many_inputs():
    node = _Counter(period_s=60.0)  # a long period: the old schedule ran 60 s ahead per input
    bus, runner = _run(node)
    try:
        pub = bus.publisher("t/in", GimbalState)
        for i in range(40):  # each wakes a step of its own
            pub.publish(GimbalState(0.0, 0.0, 0.0, 0.0, sequence=i))
            assert wait_for(lambda i=i: node.seen[-1:] == [i])
        pub.publish(GimbalState(0.0, 0.0, 0.0, 0.0, sequence=1000))
        assert wait_for(node.holding.is_set)
        pub.publish(GimbalState(0.0, 0.0, 0.0, 0.0, sequence=1001))  # pending when that step returns
        node.hold.set()
        assert wait_for(lambda: node.seen[-1:] == [1001]), node.seen[-3:]
    finally:
        node.hold.set()
        runner.request_stop()
        runner.join()
        runner.close()
        bus.close()


def test_without_inputs_the_node_steps_at_its_period():
    node = _Counter(period_s=0.01)
    bus, runner = _run(node)
    try:
        assert wait_for(lambda: node.steps >= 20)
    finally:
        runner.request_stop()
        runner.join()
        runner.close()
        bus.close()
