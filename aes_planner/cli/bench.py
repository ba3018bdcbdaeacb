"""``aes-planner bench [GROUP ...] [--quick] [--json PATH]``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from aes_planner.errors import AesPlannerError


def register(sub: argparse._SubParsersAction) -> None:
    from aes_planner.bench import GROUPS

    p = sub.add_parser(
        "bench",
        help="run benchmarks and write their JSON",
        description="Time the package's hot paths. Medians of several runs after a warm-up; "
        f"groups: {', '.join(GROUPS)} (all when none is named).",
    )
    p.add_argument("groups", nargs="*", metavar="GROUP", help="groups to run (default: all)")
    p.add_argument("--quick", action="store_true", help="fewer runs and smaller cases")
    p.add_argument("--json", metavar="PATH", help="write the figures to this JSON file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from aes_planner.bench import run_groups, write_json

    if args.json:  # a bad --json fails before minutes of benchmarks, not after
        json_path = Path(args.json)
        try:
            if json_path.is_dir():
                raise AesPlannerError(
                    f"--json {json_path} is a folder; give a file name, e.g. {json_path / 'bench.json'}"
                )
            json_path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise AesPlannerError(f"--json {json_path}: cannot write there ({exc.strerror or exc})") from None
    # Benchmarks always report their figures, whatever -v says.
    logging.getLogger("aes_planner.bench").setLevel(logging.INFO)
    rec = run_groups(args.groups, quick=args.quick)
    width = max((len(k) for k in rec.results), default=10)
    for key, r in sorted(rec.results.items()):
        print(f"{key:<{width}}  {r['value']:>12.4g} {r['unit']:<8} (runs={r['runs']})")
    if args.json:
        path = write_json(rec, args.json)
        print(f"wrote {path}")
    return 0
