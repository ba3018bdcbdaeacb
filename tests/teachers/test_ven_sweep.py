"""Bad-input sweep: VEN weight files and the ``score`` command.

A weights file that is not VEN's (random bytes, truncated, finite but huge values) is a
WeightsError; a network that overflows is a TeacherError, never a NaN score with exit 0.
"""

import io
import os
import random

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.errors import AesPlannerError
from aes_planner.teachers.base import TeacherError, WeightsError
from aes_planner.teachers.ven import MAX_ABS_WEIGHT, VENTeacher, load_ven_state_dict


@pytest.fixture(scope="module")
def ven_state():
    return {k: v.clone() for k, v in VENTeacher.random(seed=5).net.state_dict().items()}


def _small_checkpoint() -> bytes:
    buf = io.BytesIO()
    torch.save({"features.0.weight": torch.randn(4, 3), "stamp": torch.arange(5)}, buf)
    return buf.getvalue()


def _byte_cases(n: int, seed: int) -> list[bytes]:
    rng = random.Random(seed)
    good = _small_checkpoint()
    cases = []
    for i in range(n):
        if i % 3 == 0:
            cases.append(bytes(rng.randrange(256) for _ in range(rng.randint(0, 600))))
        elif i % 3 == 1:
            cases.append(good[: rng.randint(0, len(good))])
        else:
            b = bytearray(good)
            for _ in range(rng.randint(1, 20)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            cases.append(bytes(b))
    return cases


@pytest.mark.parametrize("data", _byte_cases(30, seed=1))
def test_damaged_weight_files_are_weights_errors(tmp_path, data, clean_error):
    path = tmp_path / "w.pt"
    path.write_bytes(data)
    try:
        load_ven_state_dict(path)  # a mutation may leave a readable (non-VEN) state dict
    except AesPlannerError as exc:
        assert isinstance(exc, WeightsError) and "\n" not in str(exc)


@pytest.mark.slow
@settings(max_examples=419)
@given(st.binary(max_size=3000))
def test_any_bytes_as_weights_is_a_weights_error_slow(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("w") / "w.pt"
    path.write_bytes(data)
    try:
        load_ven_state_dict(path)
    except WeightsError:
        pass


def test_non_weight_files(tmp_path, clean_error):
    clean_error(VENTeacher, tmp_path, match="not a readable PyTorch checkpoint")
    (tmp_path / "w.json").write_text('{"features.0.weight": [1, 2]}')
    clean_error(VENTeacher, tmp_path / "w.json", match="not a readable PyTorch checkpoint")
    torch.save({"features.0.weight": "a string"}, tmp_path / "s.pt")
    clean_error(VENTeacher, tmp_path / "s.pt", match="not a tensor")
    torch.save([1, 2, 3], tmp_path / "l.pt")
    clean_error(VENTeacher, tmp_path / "l.pt", match="expected a state dict")


@pytest.mark.parametrize("value", [1e30, -3e38, 2 * MAX_ABS_WEIGHT])
def test_finite_but_huge_weights_are_refused(ven_state, clean_error, value):
    state = dict(ven_state)
    state["classifier.3.weight"] = torch.full_like(state["classifier.3.weight"], value)
    clean_error(VENTeacher, state, match="trained VEN weights stay below")


def test_overflowing_network_raises_instead_of_nan(ven_state, clean_error):
    state = {k: torch.full_like(v, MAX_ABS_WEIGHT * 0.9) for k, v in ven_state.items()}
    teacher = VENTeacher(state)  # every value allowed, but the activations overflow float32
    err = clean_error(teacher.score, torch.rand(1, 3, 32, 32), match="non-finite")
    assert isinstance(err, TeacherError)


def test_score_cli_never_prints_nan(ven_state, tmp_path, cli_error):
    state = {k: torch.full_like(v, MAX_ABS_WEIGHT * 0.9) for k, v in ven_state.items()}
    torch.save(state, tmp_path / "ven.pt")
    cv2.imwrite(str(tmp_path / "a.png"), np.full((24, 32, 3), 90, np.uint8))
    for extra in ([], ["--json"]):
        cli_error(
            ["score", "--teacher", "ven", "--weights", tmp_path / "ven.pt", *extra, tmp_path / "a.png"], "non-finite"
        )


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "not an image"),
        (b"\x89PNG\r\n\x1a\n" + os.urandom(100), "not an image"),
        (b"\xff\xd8\xff\xe0" + b"\0" * 50, "not an image"),
        (b"GIF89a\x10\x00\x10\x00" + os.urandom(30), "not an image"),
        (b"BM" + b"\0" * 16 + (100000).to_bytes(4, "little") * 2 + b"\0" * 30, "100000x100000"),
    ],
)
def test_score_bad_image_files(tmp_path, cli_error, content, match):
    (tmp_path / "x.img").write_bytes(content)
    cli_error(["score", tmp_path / "x.img"], match)


def test_score_image_bomb_header_is_refused_before_decoding(tmp_path, cli_error):
    import struct
    import zlib

    chunk = b"IHDR" + struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))
    (tmp_path / "bomb.png").write_bytes(data + b"\0" * 100)
    cli_error(["score", tmp_path / "bomb.png"], "30000x30000")
    cli_error(["score", tmp_path], "is a folder; give image files")
    cli_error(["teachers", "convert-ven", tmp_path / "bomb.png", tmp_path / "out.pt"], "not a readable")
    assert not (tmp_path / "out.pt").exists()


def test_convert_ven_to_a_bad_destination(tmp_path, cli_error):
    (tmp_path / "ven.pt").write_bytes(b"never read: the destination is checked first")
    (tmp_path / "afile").write_text("x")
    cli_error(["teachers", "convert-ven", tmp_path / "ven.pt", tmp_path], "is a folder")
    cli_error(["teachers", "convert-ven", tmp_path / "ven.pt", tmp_path / "afile" / "w.pt"], "cannot write")
    assert (tmp_path / "afile").read_text() == "x"


# ----------------------------------------------------- declared sizes are checked before torch.load
def _legacy_bytes(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf, _use_new_zipfile_serialization=False)
    return buf.getvalue()


def _with_numel(data: bytes, old: bytes, numel: int) -> bytes:
    """``data`` with the storage size ``old`` (``K<n>`` after ``'cpu'`` and its memo) set to ``numel``."""
    import struct

    i = data.index(b"cpu") + len(b"cpu")
    j = data.index(old, i)
    return data[:j] + b"J" + struct.pack("<i", numel) + data[j + len(old) :]


def _zip_with_pickle(data: bytes, edit) -> bytes:
    import zipfile

    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zout:
        for info in zin.infolist():
            body = zin.read(info)
            zout.writestr(info.filename, edit(body) if info.filename.endswith("data.pkl") else body)
    return out.getvalue()


@pytest.fixture
def torch_load_never_runs(monkeypatch):
    def never(*args, **kwargs):
        pytest.fail("torch.load ran on a file whose declared sizes should have been refused first")

    monkeypatch.setattr(torch, "load", never)


def test_a_200_byte_legacy_file_declaring_gigabytes_is_refused_before_allocating(
    tmp_path, clean_error, torch_load_never_runs
):
    data = _with_numel(_legacy_bytes({"w": torch.zeros(2)}), b"K\x02", 800_000_000)
    assert len(data) < 400
    (tmp_path / "w.pt").write_bytes(data)
    clean_error(load_ven_state_dict, tmp_path / "w.pt", match="declare 3200000000 bytes")


def test_a_zip_checkpoint_declaring_more_than_its_record_is_refused_before_allocating(
    tmp_path, clean_error, torch_load_never_runs
):
    buf = io.BytesIO()
    torch.save({"w": torch.zeros(2)}, buf)
    data = _zip_with_pickle(buf.getvalue(), lambda pkl: _with_numel(pkl, b"K\x02", 300_000_000))
    (tmp_path / "w.pt").write_bytes(data)
    clean_error(load_ven_state_dict, tmp_path / "w.pt", match="its record holds 8")


def test_a_persistent_id_that_is_not_a_storage_is_a_weights_error(tmp_path, clean_error):
    # torch's own check of this is an AssertionError, which escaped as a bug.
    data = _legacy_bytes({"w": torch.zeros(2)})
    start = data.index(b"(X\x07\x00\x00\x00storage")
    end = data.index(b"Q", start)
    (tmp_path / "w.pt").write_bytes(data[:start] + b"K\x07" + data[end:])
    clean_error(load_ven_state_dict, tmp_path / "w.pt", match="not a storage")


@pytest.mark.parametrize("seed", range(40))
def test_mutated_legacy_checkpoints_are_weights_errors(tmp_path, seed):
    # The fuzzed files of the sweep: flipped bytes in the legacy (2018) format VEN is released in.
    rng = random.Random(seed)
    b = bytearray(_legacy_bytes({"features.0.weight": torch.randn(4, 3), "stamp": torch.arange(5)}))
    for _ in range(rng.randint(1, 8)):
        b[rng.randrange(len(b))] = rng.randrange(256)
    (tmp_path / "w.pt").write_bytes(bytes(b))
    try:
        load_ven_state_dict(tmp_path / "w.pt")
    except AesPlannerError as exc:
        assert isinstance(exc, WeightsError) and "\n" not in str(exc)


def test_a_tar_archive_is_refused(tmp_path, clean_error, torch_load_never_runs):
    import tarfile

    with tarfile.open(tmp_path / "w.tar", "w") as tar:
        (tmp_path / "storages").write_bytes(b"\x00" * 64)
        tar.add(tmp_path / "storages", arcname="storages")
    clean_error(load_ven_state_dict, tmp_path / "w.tar", match="tar archive")


def test_a_device_given_as_ven_weights_is_refused_unread(clean_error, torch_load_never_runs):
    from aes_planner.teachers.ven import load_ven_state_dict

    clean_error(load_ven_state_dict, "/dev/zero", match="not a regular file")
