"""A process for the two-host tests (run inside a network namespace with ``ip netns exec``)::

    python netns_peer.py hub LISTEN [CONNECT]   # a graph's hub (a Zenoh router), as the launcher is
    python netns_peer.py pub CONNECT N HZ       # once t/seq has a subscriber: N reliable messages
    python netns_peer.py watch CONNECT TOPIC... # one JSON line per message seen: topic, sequence, fields

Each prints ``ready`` once its session is open and runs until SIGTERM (``pub`` too, after its
last message, so that nothing it queued is cut off)."""

import json
import signal
import sys
import threading
import time

from aes_planner.messages import GimbalCommand, GimbalState
from aes_planner.transport import ZenohConfig, wait_any
from aes_planner.transport.zenoh_bus import ZenohBus

TYPES = {"gimbal/command": GimbalCommand, "gimbal/state": GimbalState, "t/seq": GimbalCommand}


def main(argv: list[str]) -> None:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    role = argv[0]
    if role == "hub":
        cfg = ZenohConfig(listen=(argv[1],), connect=tuple(argv[2:3]), allow_remote=True, mode="router")
    else:
        cfg = ZenohConfig(connect=(argv[1],))
    with ZenohBus(cfg) as bus:
        print("ready", flush=True)
        if role == "pub":
            n, hz = int(argv[2]), float(argv[3])
            pub = bus.publisher("t/seq", GimbalCommand)  # reliable: blocks rather than drops
            while not stop.is_set() and not any(i.topic == "t/seq" and i.subscribers for i in bus.topics(0.2)):
                pass
            for i in range(1, n + 1):
                if stop.is_set():
                    break
                pub.publish(GimbalCommand("move", 0.0, 0.0, stamp_s=time.time(), sequence=i))
                print(json.dumps({"sent": i, "t": time.time()}), flush=True)
                stop.wait(1.0 / hz)
        elif role == "watch":
            subs = [bus.subscribe(t, TYPES[t], depth=10_000) for t in argv[2:]]
            while not stop.is_set():
                if wait_any(subs, timeout_s=0.2):
                    for sub in subs:
                        for m in sub.take():
                            row = {"topic": sub.topic, "seq": m.sequence, "t": time.time()}
                            if isinstance(m, GimbalCommand):
                                row.update(kind=m.kind, pan=m.pan_rad, tilt=m.tilt_rad)
                            else:
                                row.update(
                                    pan=m.pan_rad, tilt=m.tilt_rad, goal_pan=m.goal_pan_rad, goal_tilt=m.goal_tilt_rad
                                )
                                row.update(moving=m.moving, status=m.status)
                            print(json.dumps(row), flush=True)
        stop.wait()


if __name__ == "__main__":
    main(sys.argv[1:])
