"""``aes-planner score IMAGE... [--teacher NAME] [--weights PATH] [--json]``.

Scores image files with a teacher and prints each score with the terms behind it. Images are
read as they are (no resizing here: a teacher applies only its own preprocessing, so a
224x224 image reaches VEN untouched).
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from aes_planner.errors import AesPlannerError


def register(sub: argparse._SubParsersAction) -> None:
    # Nothing heavy here: every command builds this parser, and torch takes a second to import.
    p = sub.add_parser(
        "score",
        help="score images with an aesthetic teacher and explain the scores",
        description="Score image files with a teacher and print each score with its explanation terms. "
        "Teachers: built-in 'composition' (default, no weights) and 'ven' (needs --weights), plus plugins "
        "(`aes-planner teachers list`).",
    )
    p.add_argument("images", nargs="+", metavar="IMAGE", help="image files (PNG, JPEG, ...)")
    p.add_argument("--teacher", metavar="NAME", help="teacher name (default: composition)")
    p.add_argument("--weights", metavar="PATH", help="weights file of teachers that need one (ven)")
    p.add_argument("--json", action="store_true", help="print a JSON list of {path, score, terms}")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from aes_planner.images import read_image
    from aes_planner.teachers import DEFAULT_TEACHER, get_teacher

    kwargs = {"weights": args.weights} if args.weights else {}
    teacher = get_teacher(args.teacher or DEFAULT_TEACHER, **kwargs)
    rows = []
    with torch.no_grad():
        for path in args.images:
            terms = {k: float(v[0]) for k, v in teacher.explain(read_image(path)[None]).items()}
            score = terms.pop("score")
            if not all(math.isfinite(v) for v in (score, *terms.values())):
                raise AesPlannerError(
                    f"{path}: teacher {teacher.name} gave a non-finite score or term; its weights overflow "
                    "(check the weights file)"
                )
            rows.append({"path": str(path), "score": score, "terms": terms})
    if args.json:
        json.dump(rows, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    print(f"teacher {teacher.name}: score {teacher.score_range}")
    width = max(len(r["path"]) for r in rows)
    for r in rows:
        terms = "  ".join(f"{k} {v:.3f}" for k, v in r["terms"].items())
        print(f"{r['path']:<{width}}  score {r['score']:.4f}" + (f"  [{terms}]" if terms else ""))
    return 0
