"""``aes-planner teachers list`` and ``aes-planner teachers convert-ven SRC DST``."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("teachers", help="list aesthetic teachers; convert VEN weights", description=__doc__)
    tsub = p.add_subparsers(dest="teachers_command", metavar="ACTION", required=True)
    lp = tsub.add_parser("list", help="teachers get_teacher() and --teacher accept, plugins included")
    lp.set_defaults(func=run_list)
    cp = tsub.add_parser(
        "convert-ven",
        help="write VEN weights (released layout or state dict) as a bare state dict",
        description="Reads SRC weights-only, as --weights does (training extras become inert placeholders; "
        "nothing in the file is executed), checks it is VEN, and writes DST with the bare tensors. The SHA-256 "
        "of both files is logged.",
    )
    cp.add_argument("src", metavar="SRC", help="the released checkpoint, e.g. EvaluationNet.pth.tar")
    cp.add_argument("dst", metavar="DST", help="where to write the converted weights, e.g. ven_weights.pt")
    cp.set_defaults(func=run_convert)


def run_list(args: argparse.Namespace) -> int:
    from aes_planner.teachers import DEFAULT_TEACHER, available_teachers

    for name in available_teachers():
        print(name + ("  (default)" if name == DEFAULT_TEACHER else ""))
    return 0


def run_convert(args: argparse.Namespace) -> int:
    import logging

    from aes_planner.teachers.ven import convert_checkpoint

    logging.getLogger("aes_planner.teachers.ven").setLevel(logging.INFO)
    out = convert_checkpoint(args.src, args.dst)
    print(f"wrote {out}; use it with --weights {out}")
    return 0
