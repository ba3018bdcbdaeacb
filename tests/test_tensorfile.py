"""aes_planner.tensorfile: nested trees of tensors and plain values round-trip through an .npz, and
anything else (torch.save files, object arrays, damaged bytes, oversized descriptions) is refused
without unpickling."""

import io
import json
import math
import zipfile

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner import tensorfile
from aes_planner.errors import AesPlannerError
from aes_planner.tensorfile import LegacyTorchFileError, TensorFileError


def same(a, b):
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b


def test_nested_tree_round_trip(tmp_path):
    tree = {
        "f32": torch.randn(3, 4),
        "f64": torch.randn(2, dtype=torch.float64),
        "i64": torch.arange(5),
        "i32": torch.arange(3, dtype=torch.int32),
        "u8": torch.tensor([0, 255], dtype=torch.uint8),
        "bool": torch.tensor([True, False]),
        "scalar": torch.tensor(2.5),
        "empty": torch.zeros(0, 3),
        "strided": torch.arange(12.0).reshape(3, 4).t(),
        "nd": np.arange(6, dtype=np.uint32).reshape(2, 3),
        "plain": [1, -(2**62), 0.1, "é text", True, False, None, float("nan"), float("inf"), -math.inf],
        "tuple": (1, (2.0, "x")),
        7: {"int key": {0: "a", -1: "b", "0": "c"}},
        "": {},
    }
    path = tensorfile.save(tmp_path / "t.npz", tree)
    back = tensorfile.load(path)
    assert same(tree, back)
    assert back["strided"].is_contiguous()
    back["f32"] += 1  # writable, and not shared with anything else
    assert not torch.equal(back["f32"], tree["f32"])
    assert not list(tmp_path.glob(".*tmp"))  # the temporary file was renamed into place


def test_adam_state_round_trip_resumes_identically(tmp_path):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.ReLU(), torch.nn.Linear(4, 1))
    opt = torch.optim.Adam(net.parameters(), lr=1e-2, betas=(0.8, 0.99))
    x = torch.randn(8, 3)

    def step(n, o):
        o.zero_grad()
        n(x).pow(2).mean().backward()
        o.step()

    for _ in range(3):
        step(net, opt)
    state = opt.state_dict()
    assert all(isinstance(k, int) for k in state["state"])  # int param ids: the dict keys JSON cannot hold
    tensorfile.save(tmp_path / "opt.npz", {"model": net.state_dict(), "optimizer": state})
    back = tensorfile.load(tmp_path / "opt.npz")
    assert same(dict(state), back["optimizer"])

    net2 = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.ReLU(), torch.nn.Linear(4, 1))
    net2.load_state_dict(back["model"])
    opt2 = torch.optim.Adam(net2.parameters(), lr=0.5)
    opt2.load_state_dict(back["optimizer"])
    assert opt2.param_groups[0]["lr"] == 1e-2 and opt2.param_groups[0]["betas"] == (0.8, 0.99)
    step(net, opt)
    step(net2, opt2)
    for a, b in zip(net.parameters(), net2.parameters()):
        assert torch.equal(a, b)


@pytest.mark.parametrize("zip_format", [True, False])
def test_old_torch_file_is_refused_unread(tmp_path, no_unpickling, zip_format):
    with pytest.raises(BaseException, match="unpickled"):  # the guard itself works
        torch.load(tmp_path / "anything")
    path = tmp_path / "old.pt"
    torch.save({"w": torch.zeros(2)}, path, _use_new_zipfile_serialization=zip_format)
    with pytest.raises(LegacyTorchFileError, match="older aes-planner in torch's pickle-based format") as info:
        tensorfile.load(path)
    assert str(path) in str(info.value)


def test_object_arrays_are_refused_unread(tmp_path, no_unpickling):
    path = tmp_path / "obj.npz"
    tensorfile.save(path, {"w": np.zeros(3)})
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["a0"] = np.array([{"x": 1}, None], dtype=object)  # np.savez pickles object arrays on write
    np.savez(path, **arrays)
    with pytest.raises(TensorFileError, match="dtype object"):
        tensorfile.load(path)


def _rewrite_tree(path, text: bytes, **extra):
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["__tree__"] = np.frombuffer(text, dtype=np.uint8)
    np.savez(path, **arrays, **extra)


@pytest.mark.parametrize(
    "tree, match",
    [
        ({"format": "other", "version": 1, "tree": 1}, "not an aes-planner tensor file"),
        ({"format": tensorfile.FORMAT, "version": 2, "tree": 1}, "version 2"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"pickle": "a0"}}, "unknown tag"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"tensor": "a9"}}, "not in the file"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"tensor": "__tree__"}}, "not in the file"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"list": [{"tensor": "a0"}] * 2}}, "second time"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"dict": [[1.5, 1]]}}, "bad or repeated key"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"dict": [["a", 1], ["a", 2]]}}, "repeated key"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"float": "huge"}}, "unknown tag"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": {"a": 1, "b": 2}}, "not a known node"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": 1.0e400}, "damaged|non-finite"),
        ({"format": tensorfile.FORMAT, "version": 1, "tree": 1}, "does not name"),  # a0 is left over
    ],
)
def test_bad_descriptions_are_refused(tmp_path, tree, match):
    path = tmp_path / "t.npz"
    tensorfile.save(path, {"w": torch.zeros(2)})
    text = json.dumps(tree).replace("Infinity", "1e400").encode()
    _rewrite_tree(path, text)
    with pytest.raises(TensorFileError, match=match):
        tensorfile.load(path)


def test_oversized_deep_or_broken_json_is_refused(tmp_path):
    path = tmp_path / "t.npz"
    tensorfile.save(path, {})
    for text, match in [
        (b" " * (tensorfile.MAX_JSON_BYTES + 1), "exceeds the size limit"),
        (b"[" * 100_000, "damaged"),
        (b'{"format": NaN}', "damaged"),
        (b"\xff\xfe", "damaged"),
    ]:
        _rewrite_tree(path, text)
        with pytest.raises(TensorFileError, match=match):
            tensorfile.load(path)
    deep = {"list": []}
    for _ in range(tensorfile.MAX_DEPTH + 2):
        deep = {"list": [deep]}
    _rewrite_tree(path, json.dumps({"format": tensorfile.FORMAT, "version": 1, "tree": deep}).encode())
    with pytest.raises(TensorFileError, match="deeper"):
        tensorfile.load(path)


def test_size_cap_is_checked_before_reading(tmp_path):
    path = tensorfile.save(tmp_path / "t.npz", {"w": torch.zeros(1000)})
    assert tensorfile.load(path, max_bytes=4000)["w"].shape == (1000,)
    with pytest.raises(TensorFileError, match="size limit"):
        tensorfile.load(path, max_bytes=3999)


def _npy_bytes(arr):
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def test_other_files_are_refused(tmp_path):
    cases = {
        "missing.npz": None,
        "npy.npz": lambda p: p.write_bytes(_npy_bytes(np.zeros(3))),
        "plain.npz": lambda p: np.savez(p, x=np.zeros(3)),
        "zip.npz": lambda p: zipfile.ZipFile(p, "w").writestr("x.txt", "hello"),
        "text.npz": lambda p: p.write_text("hello"),
        "empty.npz": lambda p: p.write_bytes(b""),
    }
    for name, make in cases.items():
        path = tmp_path / name
        if make:
            make(path)
        with pytest.raises(TensorFileError) as info:
            tensorfile.load(path)
        assert str(path) in str(info.value), name
        assert ("does not exist" in str(info.value)) == (name == "missing.npz"), info.value
    with pytest.raises(TensorFileError, match="folder"):
        tensorfile.load(tmp_path)


def test_unstorable_values_are_refused_on_write(tmp_path):
    for tree, match in [
        ({"x": object()}, "object"),
        ({(1, 2): 1}, "key of type tuple"),
        ({True: 1}, "key of type bool"),
        ({"x": torch.zeros(2, dtype=torch.bfloat16)}, "bfloat16"),
        ({"x": np.array(["a"])}, "numeric"),
        ({"x": {1, 2}}, "set"),
    ]:
        with pytest.raises(TensorFileError, match=match):
            tensorfile.save(tmp_path / "t.npz", tree)
        assert not list(tmp_path.iterdir())  # nothing written, not even a temporary file


@given(st.binary(max_size=300))
def test_random_bytes_are_refused(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("tf") / "x.npz"
    path.write_bytes(data)
    with pytest.raises(AesPlannerError):
        tensorfile.load(path)


@pytest.fixture(scope="module")
def valid_bytes(tmp_path_factory):
    path = tmp_path_factory.mktemp("tf") / "good.npz"
    tensorfile.save(path, {"w": torch.arange(6.0), "d": {0: [1, "x"]}})
    return path.read_bytes()


@given(st.data())
def test_damaged_files_load_or_are_refused(tmp_path_factory, valid_bytes, data):
    raw = bytearray(valid_bytes)
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    else:
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path_factory.mktemp("tf") / "x.npz"
    path.write_bytes(bytes(raw))
    try:
        tree = tensorfile.load(path)
    except AesPlannerError as exc:
        assert str(path) in str(exc)
    else:
        assert isinstance(tree, dict)  # a change the archive does not detect (e.g. in a zip comment)
