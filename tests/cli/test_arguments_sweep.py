"""Command-line arguments: an argument error (unknown choice, missing or malformed value) and an empty
option value are one ``error:`` line with exit 2, never taken for the default.
"""

import pytest

from aes_planner.cli import main


@pytest.mark.parametrize(
    "argv",
    [
        ["score", "x.png", "--teacher", ""],
        ["score", "x.png", "--teacher", "  "],
        ["score", "x.png", "--teacher="],
        ["score", ""],
        ["suggest", "x", "--scorer", ""],
        ["launch", "sim_closed_loop", "--connect", ""],
        ["train", "--out", ""],
    ],
)
def test_an_empty_option_value_is_refused_not_taken_for_the_default(cli_error, argv):
    cli_error(argv, "an empty value", seconds=10)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["suggest", "x", "--preset", "nonsense"], "invalid choice"),
        (["gimbal", "nonsense"], "invalid choice"),
        (["nonsense"], "invalid choice"),
        (["sim", "render", "--views", "many", "--scene", "indoor:1", "--out", "o"], "invalid int value"),
        (["score"], "required"),
    ],
)
def test_argument_errors_are_one_line_too(capsys, argv, match):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: ") and match in err, err
