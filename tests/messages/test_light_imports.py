"""A consumer of the planner's topics needs numpy, not torch: the messages and the Zenoh client side
import, encode, decode and travel over Zenoh in an interpreter where torch cannot be imported."""

from tests.helpers import run_python_without
from tests.transport.conftest import free_port

CODE = """
import numpy as np
import aes_planner.messages as m
from aes_planner.geometry.camera import Intrinsics
from aes_planner.transport import ZenohConfig, wait_any
from aes_planner.transport.zenoh_bus import ZenohBus

frame = m.PosedFrame(np.zeros((4, 6, 3), np.uint8), Intrinsics(5.0, 5.0, 3.0, 2.0, 6, 4), np.eye(4), stamp_s=1.0)
suggestion = m.ViewSuggestion(2.0, [m.Candidate(np.eye(4), 0.5, 0.9, 0.1, 0.2, {"thirds": 0.3})], kind="waypoint")
every_type = [
    frame,
    suggestion,
    m.GimbalCommand("move", 0.1, 0.2),
    m.GimbalState(0.1, 0.2, 0.3, 0.4, True, (30.0, 31.0), ("pan: overload",)),
    m.Diagnostics(1.0, "planner", "exploring", {"frames_in": 3}, {"latency_s": 0.1}),
    m.PlannerRequest("suggest"),
    m.Clock(10_000_000, 1, {"gimbal/state": 1}),
    m.ClockAck("gimbal", 1, 20_000_000, {"gimbal/state": 1}),
    m.DroneState(3.0, np.eye(4), mode="OFFBOARD", armed=True, system_id=1),
]
assert {type(x).TYPE_NAME for x in every_type} == set(m.MESSAGE_TYPES)
for msg in every_type:
    assert m.encode(m.decode(m.encode(msg))) == m.encode(msg), msg
    assert m.to_jsonable(msg)["type"] == type(msg).TYPE_NAME
with ZenohBus(ZenohConfig(listen=("tcp/127.0.0.1:PORT",))) as bus:
    sub = bus.subscribe("planner/suggestion", m.ViewSuggestion, depth=1)
    bus.publisher("planner/suggestion", m.ViewSuggestion, latched=True).publish(suggestion)
    assert wait_any([sub], timeout_s=10.0), "no suggestion over zenoh"
    got = sub.latest()
assert got.kind == "waypoint" and got.best.view.shape == (5,)
print("ok", sorted(k for k in sys.modules if k.split(".")[0] in ("torch", "numba")))
"""


def test_messages_and_the_zenoh_client_work_with_torch_blocked():
    out = run_python_without(("torch",), CODE.replace("PORT", str(free_port())))
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip() == "ok ['torch']"  # torch only as the blocked entry; numba never loaded
