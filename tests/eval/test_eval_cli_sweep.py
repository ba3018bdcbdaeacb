"""Bad-input sweep of ``eval search`` and ``eval field``: every bad option or scene ends in one
``error:`` line with exit 2, before any scene is rendered.
"""

import pytest

EVAL_CASES = [
    (["eval", "search", "--scene", "indoor:1", "--oracle-step-deg", "1e-9"], "oracle_step_deg"),
    (["eval", "search", "--scene", "indoor:1", "--oracle-step-deg", "1e9"], "oracle_step_deg"),
    (["eval", "search", "--scene", "indoor:1", "--views", "999"], "views"),
    (["eval", "search", "--scene", "indoor:1", "--views", ""], "views"),
    (["eval", "search", "--scenes", "0"], "--scenes"),
    (["eval", "search", "--scenes", "-1"], "--scenes"),
    (["eval", "search", "--scene", "indoor:1", "--scene", "nowhere:1"], "unknown scene family"),
    (["eval", "field", "--scene", "indoor:1", "--targets", "100000000"], "targets"),
    (["eval", "field", "--scene", "indoor:1", "--render-width", "0"], "render_width_px"),
    (["eval", "field", "--scenes", "0"], "--scenes"),
    (["eval", "field", "--scenes", "100000000"], "--scenes"),
]


@pytest.mark.parametrize("argv, match", EVAL_CASES, ids=range(len(EVAL_CASES)))
def test_eval_bad_input(work, cli_error, argv, match):
    out = ["--out", str(work / "o")]
    cli_error([*argv, *out], match, seconds=30)
