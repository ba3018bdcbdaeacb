"""examples/suggestion_consumer.py, run as a separate process, prints what the planner suggests."""

import subprocess
import sys
from pathlib import Path

from aes_planner.messages import ViewSuggestion
from aes_planner.messages.samples import sample_messages
from aes_planner.transport import ZenohConfig

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "suggestion_consumer.py"


def test_example_consumer_prints_the_latched_suggestion(endpoint):
    from aes_planner.transport.zenoh_bus import ZenohBus

    with ZenohBus(ZenohConfig(listen=(endpoint,), connect=())) as bus:
        bus.publisher("planner/suggestion", ViewSuggestion, latched=True).publish(sample_messages()["ViewSuggestion"])
        out = subprocess.run(
            [sys.executable, str(EXAMPLE), "--connect", endpoint, "--count", "1"],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert out.returncode == 0, out.stderr
    assert "#2 field v4: go to x=0.50 y=-0.20 z=1.20 m" in out.stdout and "pan +17.2" in out.stdout
