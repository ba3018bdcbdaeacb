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
from pathlib import Path

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


def read_image(path: str | Path):  # -> Tensor [3, H, W] float in [0, 1]
    """An image file as RGB float in [0, 1]; grey is repeated, alpha dropped, 16 bit kept."""
    import cv2
    import numpy as np
    import torch

    path = Path(path)
    if not path.is_file():
        raise AesPlannerError(f"{path}: no such image file")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        raise AesPlannerError(f"{path}: not an image OpenCV can read (PNG, JPEG, TIFF, BMP, ...)")
    if raw.dtype == np.uint8:
        arr = raw.astype(np.float32) / 255.0
    elif raw.dtype == np.uint16:
        arr = raw.astype(np.float32) / 65535.0
    elif raw.dtype in (np.float32, np.float64):
        arr = np.clip(np.nan_to_num(raw.astype(np.float32)), 0.0, 1.0)
    else:
        raise AesPlannerError(f"{path}: unsupported pixel type {raw.dtype}; save it as 8- or 16-bit PNG")
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    elif arr.shape[2] == 4:
        arr = arr[..., [2, 1, 0]]  # BGRA -> RGB, alpha dropped
    elif arr.shape[2] == 3:
        arr = arr[..., ::-1]
    else:
        raise AesPlannerError(f"{path}: {arr.shape[2]} channels; expected grey, RGB or RGBA")
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1).contiguous()


def run(args: argparse.Namespace) -> int:
    import torch

    from aes_planner.teachers import DEFAULT_TEACHER, get_teacher

    kwargs = {"weights": args.weights} if args.weights else {}
    teacher = get_teacher(args.teacher or DEFAULT_TEACHER, **kwargs)
    rows = []
    with torch.no_grad():
        for path in args.images:
            terms = {k: float(v[0]) for k, v in teacher.explain(read_image(path)[None]).items()}
            score = terms.pop("score")
            rows.append({"path": str(path), "score": score, "terms": terms})
    if args.json:
        json.dump(rows, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    print(f"teacher {teacher.name}: score {teacher.score_range}")
    width = max(len(r["path"]) for r in rows)
    for r in rows:
        terms = "  ".join(f"{k} {v:.3f}" for k, v in r["terms"].items())
        score = f"{r['score']:.4f}" if math.isfinite(r["score"]) else str(r["score"])
        print(f"{r['path']:<{width}}  score {score}" + (f"  [{terms}]" if terms else ""))
    return 0
