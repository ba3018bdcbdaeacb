"""``aes-planner warmup``: compile the rasterizer's kernels and the composition teacher's head
into numba's on-disk cache.

numba compiles them on their first use after an install (~40 s on two cores) and caches them
beside the package, so later processes load them in ~0.5 s. ``make install`` (and with it
``make demo`` and ``make test``) runs this once; run it after ``pip install`` on a robot so that
the planner's first suggestion is not the one that waits.
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "warmup",
        help="compile the rasterizer's kernels and the composition head ahead of first use (once per install)",
        description=__doc__,
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from aes_planner.gaussians import numba_backend
    from aes_planner.gaussians.rasterize import resolve_backend
    from aes_planner.gaussians.warmup import COMPILED_AFTER_S
    from aes_planner.teachers import get_teacher

    backend = resolve_backend()
    if backend != "numba":
        print(f"the rasterizer runs on the {backend} backend: nothing to compile")
    else:
        print("compiling the rasterizer's kernels (or loading them from numba's cache) ...", flush=True)
        took_s = numba_backend.warmup()
        how = "compiled" if took_s > COMPILED_AFTER_S else "loaded from numba's cache"
        print(f"rasterizer kernels ready: {how} in {took_s:.1f} s")
    print("compiling the composition teacher's head (or loading it from numba's cache) ...", flush=True)
    took_s = get_teacher("composition").warm()
    if took_s is None:
        print("the composition head runs in torch (numba is not importable): nothing to compile")
    else:
        how = "compiled" if took_s > COMPILED_AFTER_S else "loaded from numba's cache"
        print(f"composition head ready: {how} in {took_s:.1f} s")
    return 0
