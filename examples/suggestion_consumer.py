"""A separate program that follows the planner's suggestions over Zenoh, as a flight stack or a UI
would. Run the planner (`aes-planner launch launch/sim_closed_loop.yaml --processes`), then:

    python examples/suggestion_consumer.py                       # joins tcp/127.0.0.1:7390
    python examples/suggestion_consumer.py --connect tcp/192.168.1.5:7390 --count 3

It needs only the aes-planner package (for the message types and the bus), not torch.
"""

import argparse
import math

from aes_planner.messages import ViewSuggestion
from aes_planner.transport import ZenohConfig, wait_any
from aes_planner.transport.zenoh_bus import ZenohBus


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", default="tcp/127.0.0.1:7390", help="a Zenoh endpoint of the planner's network")
    parser.add_argument("--count", type=int, default=0, help="stop after this many suggestions (0 = never)")
    args = parser.parse_args()

    with ZenohBus(ZenohConfig(connect=(args.connect,))) as bus:
        # depth=1: only the newest suggestion matters; the topic is latched, so the last one
        # published before we joined arrives first.
        sub = bus.subscribe("planner/suggestion", ViewSuggestion, depth=1)
        seen = 0
        try:
            while args.count == 0 or seen < args.count:
                if not wait_any([sub], timeout_s=1.0):
                    continue
                msg = sub.latest()
                seen += 1
                best = msg.best
                if best is None:
                    print(f"#{msg.sequence}: nothing better to suggest")
                    continue
                x, y, z, yaw, pitch = best.view
                line = (
                    f"#{msg.sequence} field v{msg.field_version}: go to x={x:.2f} y={y:.2f} z={z:.2f} m, "
                    f"yaw {math.degrees(yaw):+.1f} deg, pitch {math.degrees(pitch):+.1f} deg "
                    f"(score {best.score:.3f}, coverage {best.coverage:.0%})"
                )
                if best.pan_rad is not None:
                    line += f" | pan {math.degrees(best.pan_rad):+.1f} tilt {math.degrees(best.tilt_rad):+.1f} deg"
                print(line, flush=True)
        except KeyboardInterrupt:
            pass
        if sub.rejected:
            print(f"{sub.rejected} malformed suggestion(s) rejected: {sub.last_error}")


if __name__ == "__main__":
    main()
