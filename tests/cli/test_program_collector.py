"""The program's garbage collector (:func:`aes_planner.cli.main` without ``argv``): off through the
start-up's imports, their objects frozen before the command runs, everything frozen for the exit;
a call with ``argv`` (tests, other code) leaves the collector alone."""

import gc
import subprocess
import sys

from aes_planner.bench.search import _SUGGEST_IMPORTS
from aes_planner.cli import main

#: A probe run before the CLI in a fresh process: it notes every collection that starts once torch
#: is being imported (the few while Python imports ``aes_planner.cli`` itself come before the
#: program's start) and whether anything was frozen then; at exit (its atexit handler is
#: registered before torch's and runs after them) it prints those collections, those of them run
#: with nothing frozen, the freeze count and whether the collector is on.
_PROBE = (
    "import atexit, gc, sys\n"
    "seen = []\n"
    "gc.callbacks.append(lambda phase, info: phase == 'start' and 'torch' in sys.modules"
    " and seen.append(gc.get_freeze_count()))\n"
    "atexit.register(lambda: print(len(seen), sum(1 for f in seen if f == 0), gc.get_freeze_count(), gc.isenabled()))\n"
)


def _probe(body: str) -> tuple[int, int, int, bool]:
    out = subprocess.run([sys.executable, "-c", _PROBE + body], capture_output=True, text=True, timeout=600)
    collections, unfrozen, frozen, enabled = out.stdout.strip().splitlines()[-1].split()
    return int(collections), int(unfrozen), int(frozen), enabled == "True"


def test_the_program_imports_without_collections_and_freezes_them(tmp_path):
    """`aes-planner suggest` builds its parser (importing torch, numba's users and the package,
    ~200k objects: each full collection among them cost ~0.1 s) with the collector off, then runs
    the command with them frozen; here the command fails on a missing folder once the start-up is
    over, and the exit finds everything frozen and the collector on."""
    missing = tmp_path / "nowhere"
    body = (
        f"from aes_planner.cli import main\nsys.argv = ['aes-planner', 'suggest', {str(missing)!r}]\nsys.exit(main())\n"
    )
    collections, unfrozen, frozen, enabled = _probe(body)
    assert unfrozen == 0, f"{unfrozen} of {collections} collections ran before the start-up was frozen"
    assert frozen > 100_000  # torch and the rest, frozen (a freeze count is a count of objects)
    assert enabled


def test_suggest_imports_its_kernels_with_the_start_up():
    """`suggest` imports what it computes with (numba and the rasterizer's kernels among it,
    ~230 modules) with the start-up, before anything is frozen, rather than at its first render
    with the collector on; the probe's finder notes the freeze count when the kernels' module is
    looked for."""
    watch = (
        "class Watch:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'aes_planner.gaussians.kernels':\n"
        "            print('kernels looked for, frozen', gc.get_freeze_count())\n"
        "sys.meta_path.insert(0, Watch())\n"
    )
    body = (
        "from aes_planner.cli import main\nsys.argv = ['aes-planner', 'suggest', '/nowhere/at/all']\nsys.exit(main())\n"
    )
    out = subprocess.run([sys.executable, "-c", _PROBE + watch + body], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "nowhere" in out.stderr, out.stderr[-2000:]  # the folder error, after the start-up
    assert "kernels looked for, frozen 0" in out.stdout.splitlines(), out.stdout


def test_the_bench_imports_as_the_program_does():
    """`bench search`'s import-only process (`search.cold_suggest.imports_ms`) sets the collector as
    the program does: the difference of the two processes is the suggestion, not a start-up made
    cheaper in one of them only."""
    collections, unfrozen, frozen, enabled = _probe(_SUGGEST_IMPORTS)
    assert unfrozen == 0 and frozen > 100_000 and enabled, (collections, unfrozen, frozen, enabled)


def test_main_with_argv_leaves_the_collector_alone(capsys):
    """A test or a script calling ``main([...])`` keeps its own collector: nothing of its process
    is frozen (its uncollected garbage would stay for good) and the collector stays on."""
    before = gc.get_freeze_count()
    assert main([]) == 2  # no command: the help, status 2
    assert "usage:" in capsys.readouterr().out
    assert gc.isenabled() and gc.get_freeze_count() == before
