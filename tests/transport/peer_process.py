"""A peer for the restart tests, run as ``python peer_process.py ENDPOINT MODE TAG``: publishes
``GimbalState`` (status = TAG) at 20 Hz and answers ``gimbal/query``; MODE ``listen`` makes it
the hub on ENDPOINT, ``connect`` connects to it. Runs until killed."""

import sys
import time

from aes_planner.messages import GimbalState, PlannerRequest
from aes_planner.transport import ZenohConfig
from aes_planner.transport.zenoh_bus import ZenohBus

endpoint, mode, tag = sys.argv[1:4]
cfg = ZenohConfig(listen=(endpoint,), connect=()) if mode == "listen" else ZenohConfig(connect=(endpoint,))
bus = ZenohBus(cfg)
bus.serve("gimbal/query", PlannerRequest, GimbalState, lambda r: GimbalState(0, 0, 0, 0, status=tag))
pub = bus.publisher("gimbal/state", GimbalState, latched=True)
print("ready", flush=True)
i = 0
while True:
    i += 1
    pub.publish(GimbalState(0.1, 0.2, 0.1, 0.2, sequence=i, status=tag))
    time.sleep(0.05)
