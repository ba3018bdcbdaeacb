"""Bad-input sweep of the field model's checkpoint loader (aes_planner.field.model) and of
``eval field --model``: damaged, truncated, random and pickle-based files are refused with a
one-line ``ModelError`` naming the file, and nothing in them is ever unpickled.
"""

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.errors import AesPlannerError
from tests.helpers import Evil, corrupt_checkpoint, write_checkpoint

CKPT_CASES = ["nan", "huge", "shape", "state_str", "no_config", "channels", "channels_str", "size", "objects"]


@pytest.mark.parametrize("how", CKPT_CASES)
def test_field_checkpoint_loader_refuses_damaged_files(tmp_path, checkpoint, clean_error, capsys, how):
    from aes_planner.field.model import load_model

    path = write_checkpoint(tmp_path / "model.npz", corrupt_checkpoint(checkpoint, how), how)
    clean_error(load_model, path, match=str(path))
    assert "unpickled!" not in capsys.readouterr().out


@pytest.mark.parametrize("cut", [0, 10, 200, -100])
def test_field_checkpoint_loader_refuses_truncated_files(tmp_path, checkpoint, clean_error, cut):
    from aes_planner.field.model import load_model

    write_checkpoint(tmp_path / "good.npz", checkpoint)
    assert load_model(tmp_path / "good.npz") is not None
    raw = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "bad.npz").write_bytes(raw[:cut])
    clean_error(load_model, tmp_path / "bad.npz", match="bad.npz")


def test_field_checkpoint_loader_refuses_an_old_torch_file(tmp_path, checkpoint, clean_error, capsys, request):
    from aes_planner.field.model import load_model

    torch.save({**checkpoint, "extra": Evil()}, tmp_path / "model.pt")
    request.getfixturevalue("no_unpickling")
    error = clean_error(load_model, tmp_path / "model.pt", match="model.pt")
    assert "pickle-based format, which is never loaded; retrain with `aes-planner train`" in str(error)
    assert "unpickled!" not in capsys.readouterr().out


def test_eval_field_model_flag_refuses_a_damaged_checkpoint(work, checkpoint, cli_error):
    write_checkpoint(work / "nan.npz", corrupt_checkpoint(checkpoint, "nan"))
    cli_error(["eval", "field", "--scene", "indoor:1", "--model", work / "nan.npz", "--out", work / "o"], "NaN")


@given(st.binary(max_size=300))
def test_field_checkpoint_loader_random_bytes(tmp_path_factory, data):
    from aes_planner.field.model import read_checkpoint

    path = tmp_path_factory.mktemp("ck") / "x.npz"
    path.write_bytes(data)
    with pytest.raises(AesPlannerError):
        read_checkpoint(path)


@given(st.data())
def test_field_checkpoint_loader_damaged_bytes(tmp_path_factory, checkpoint_bytes, data):
    from aes_planner.field.model import ModelError, load_model

    raw = bytearray(checkpoint_bytes)
    for _ in range(data.draw(st.integers(1, 3))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path_factory.mktemp("ck") / "x.npz"
    path.write_bytes(bytes(raw[: data.draw(st.integers(1, len(raw)))]))
    try:
        load_model(path)  # a change the archive cannot see (padding, a name byte of the JSON) may load
    except ModelError as exc:
        assert "x.npz" in str(exc) and "\n" not in str(exc)


@pytest.fixture(scope="module")
def checkpoint_bytes(checkpoint, tmp_path_factory):
    return write_checkpoint(tmp_path_factory.mktemp("ck") / "good.npz", checkpoint).read_bytes()
