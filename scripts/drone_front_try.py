"""One candidate drone one-shot ``balanced`` (``FREE_MODE_PRESETS`` patched in this process) on the
12 drone validation scenes of the drone front rule (docs/results/drone_front_s29/rule.md), one
search seed; ``today`` also runs ``fast`` and is main's preset.

    .venv/bin/python scripts/drone_front_try.py k4 0 docs/results/drone_front_s29/validation
"""

from __future__ import annotations

import sys

import aes_planner.search.config as c

#: name -> the drone's one-shot ``balanced`` fields (None: as committed; {}: the rig's one-shot preset)
VARIANTS = {
    "today": dict(samples_per_segment=32, top_k=3, screen_keep=0, steps=25, explore_keep=0),
    "screen": dict(samples_per_segment=32, top_k=3, screen_keep=128, steps=25, explore_keep=0),
    "screen20": dict(samples_per_segment=32, top_k=3, screen_keep=128),
    "rig": {},
    "dense": dict(samples_per_segment=64, top_k=3, screen_keep=128, steps=25, explore_keep=0),
    "k4": dict(samples_per_segment=32, top_k=4, screen_keep=128, steps=25, explore_keep=0),
}
SCENES = [
    "indoor:500",
    "outdoor:501",
    "tabletop:502",
    "gallery:503",
    "indoor:504",
    "outdoor:505",
    "tabletop:504",
    "gallery:505",
    "tabletop:500",
    "gallery:501",
    "indoor:502",
    "outdoor:503",
]


def main(argv: list[str]) -> int:
    from aes_planner.cli import main as cli

    variant, seed, out = argv
    c.FREE_MODE_PRESETS["balanced"] = VARIANTS[variant]
    methods = "field_fast,field_balanced,oracle" if variant == "today" else "field_balanced,oracle"
    args = ["eval", "search"] + [a for s in SCENES for a in ("--scene", s)]
    args += ["--modes", "drone", "--methods", methods, "--no-ablations", "--search-seed", seed]
    return cli([*args, "--json", f"{out}/{variant}_{seed}.json"])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
