"""Output destinations of the commands that write (``suggest``, ``eval``, ``train``, ``demo``) are
checked before the work starts and nothing is written outside them; an OS error on a named file is
one ``error:`` line with exit 2, not a bug report.
"""

from pathlib import Path

import pytest

from aes_planner.cli import main
from tests.helpers import tree


def out_cases(w):
    return [
        (["suggest", w / "nowhere", "--json", w], "is a folder"),
        (["suggest", w / "nowhere", "--json", w / "a_file" / "x.json"], "not a folder"),
        (["suggest", w / "nowhere", "--out", w / "a_file"], "not a folder"),
        (["suggest", w / "nowhere", "--out", w / "a_file" / "o"], "cannot create"),
        (["suggest", w / "nowhere", "--threads", "0"], "--threads"),
        (["suggest", w / "nowhere", "--threads", "100000"], "--threads"),
        (["eval", "search", "--scene", "indoor:1", "--json", w], "is a folder"),
        (["eval", "search", "--scene", "indoor:1", "--out", w / "a_file"], "not a folder"),
        (["eval", "field", "--scene", "indoor:1", "--out", w / "a_file"], "not a folder"),
        (["eval", "field", "--scene", "indoor:1", "--out", w / "o", "--json", w], "is a folder"),
        (["train", "--out", w / "a_file", "--cache", w / "cache"], "--out"),
        (["train", "--out", w / "o", "--cache", w / "a_file"], "--cache"),
        (["train", "--out", w / "o", "--cache", w / "a_file" / "c"], "--cache"),
        (["demo", "--out", w / "a_file"], "not a folder"),
        (["demo", "--out", w / "a_file" / "run"], "cannot create"),
    ]


@pytest.mark.parametrize("i", range(13))
def test_output_destinations_are_checked_before_the_work(work, cli_error, i):
    argv, match = out_cases(work)[i]
    before = tree(work)
    cli_error(argv, match, seconds=30)
    assert tree(work) - before <= {Path("cache"), Path("o")}  # at most the other (good) folder


def test_os_errors_on_a_named_file_are_one_line_not_a_bug(monkeypatch, capsys):
    import aes_planner.cli.sim as sim_cli

    def full_disk(args):
        raise OSError(28, "No space left on device", "/data/out.png")

    monkeypatch.setattr(sim_cli, "run_families", full_disk)
    assert main(["sim", "families"]) == 2
    err = capsys.readouterr().err
    assert err == "error: /data/out.png: No space left on device\n"
