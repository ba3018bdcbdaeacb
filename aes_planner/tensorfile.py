"""Tensor files without pickle: a nested tree of tensors, arrays and plain values in an ``.npz``.

The project's own files (field checkpoints with their optimizer state, :class:`Gaussians` files)
are written by :func:`save` and read by :func:`load`, which never unpickles anything: it reads
with ``np.load(path, allow_pickle=False)`` and checks every entry before it is used.

Format (``FORMAT``, version ``VERSION``): a numpy ``.npz`` archive holding

- one uint8 array ``__tree__``: UTF-8 JSON ``{"format": FORMAT, "version": VERSION, "tree": NODE}``;
- one array per tensor or ndarray of the tree, named ``a0``, ``a1``, ... in the order met.

A NODE is a JSON string, integer, finite number, true/false or null, or an object with exactly one
tag: ``{"tensor": "a0"}`` / ``{"ndarray": "a1"}`` (the array of that name), ``{"list": [NODE...]}``,
``{"tuple": [NODE...]}``, ``{"dict": [[KEY, NODE]...]}`` (KEY a string or an integer, order kept)
or ``{"float": "nan" | "inf" | "-inf"}``. Arrays are numeric (bool, signed/unsigned integers,
float16/32/64); a tensor comes back as a CPU torch tensor of its dtype.
"""

from __future__ import annotations

import json
import math
import os
import secrets
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aes_planner.errors import AesPlannerError

__all__ = ["FORMAT", "VERSION", "TensorFileError", "load", "read_npz", "save"]

FORMAT = "aes-planner-tensorfile"
VERSION = 1
_TREE = "__tree__"
#: Largest JSON description read (bytes), deepest nesting, most arrays, largest total array size.
MAX_JSON_BYTES = 16 * 2**20
MAX_DEPTH = 64
MAX_ARRAYS = 100_000
MAX_BYTES = 2**32
_DTYPES = {
    np.dtype(t)
    for t in ("bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float16", "float32")
} | {np.dtype("float64")}
#: numpy dtypes a torch tensor may have here (torch's uint16+ support is partial: kept as ndarrays).
_TORCH_DTYPES = {np.dtype(t) for t in ("bool", "int8", "int16", "int32", "int64", "uint8", "float16", "float32")} | {
    np.dtype("float64")
}
_NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


class TensorFileError(AesPlannerError):
    """A file that :func:`load` refuses, or a tree that :func:`save` cannot store (the message
    names the file and what is wrong; callers add what to do)."""


class LegacyTorchFileError(TensorFileError):
    """A file written by ``torch.save`` (pickle-based): never loaded."""


# ---------------------------------------------------------------------------------- writing
def save(path: str | Path, tree: Any) -> Path:
    """Write ``tree`` to ``path`` atomically (a temporary file in the same folder, then a rename)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    described = _describe(tree, arrays, "tree", 0, path)
    text = json.dumps({"format": FORMAT, "version": VERSION, "tree": described}, allow_nan=False)
    arrays[_TREE] = np.frombuffer(text.encode(), dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "xb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _describe(obj: Any, arrays: dict, where: str, depth: int, path: Path) -> Any:
    if depth > MAX_DEPTH:
        raise TensorFileError(f"{path}: {where} is nested deeper than {MAX_DEPTH} levels")
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (int, np.integer)) and not isinstance(obj, np.bool_):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else {"float": "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")}
    if isinstance(obj, torch.Tensor):
        a = obj.detach().cpu().contiguous()
        if a.dtype == torch.bfloat16 or a.is_complex() or a.is_quantized:
            raise TensorFileError(f"{path}: {where} is a {a.dtype} tensor; only bool, integer and float16/32/64 store")
        arr = a.numpy()
        if arr.dtype not in _TORCH_DTYPES:
            raise TensorFileError(f"{path}: {where} is a {a.dtype} tensor, which this format does not store")
        return {"tensor": _add(arrays, arr)}
    if isinstance(obj, np.ndarray):
        if obj.dtype not in _DTYPES:
            raise TensorFileError(f"{path}: {where} is an array of dtype {obj.dtype}; only numeric arrays store")
        return {"ndarray": _add(arrays, np.ascontiguousarray(obj))}
    if isinstance(obj, (list, tuple)):
        items = [_describe(v, arrays, f"{where}[{i}]", depth + 1, path) for i, v in enumerate(obj)]
        return {"tuple" if isinstance(obj, tuple) else "list": items}
    if isinstance(obj, dict):
        pairs = []
        for k, v in obj.items():
            if isinstance(k, np.integer):
                k = int(k)
            if not (isinstance(k, str) or (isinstance(k, int) and not isinstance(k, bool))):
                raise TensorFileError(f"{path}: {where} has a key of type {type(k).__name__}; keys are str or int")
            pairs.append([k, _describe(v, arrays, f"{where}[{k!r}]", depth + 1, path)])
        return {"dict": pairs}
    raise TensorFileError(f"{path}: {where} is a {type(obj).__name__}, which this format does not store")


def _add(arrays: dict, arr: np.ndarray) -> str:
    name = f"a{len(arrays)}"
    arrays[name] = arr
    return name


# ---------------------------------------------------------------------------------- reading
def load(path: str | Path, *, max_bytes: int = MAX_BYTES) -> Any:
    """The tree of a file written by :func:`save`, tensors on the CPU. Any other file (a
    ``torch.save`` file, damaged bytes, object arrays, arrays beyond ``max_bytes`` in total) is a
    :class:`TensorFileError` naming the file; nothing is ever unpickled."""
    path = Path(path)
    if not path.is_file():
        raise TensorFileError(f"{path} does not exist" + (" (it is a folder)" if path.is_dir() else ""))
    with open(path, "rb") as f:
        head = f.read(8)
    if head[:1] == b"\x80":  # a pickle protocol opcode: torch.save's legacy format, or a bare pickle
        raise LegacyTorchFileError(_legacy(path))
    if head[:4] != b"PK\x03\x04":
        raise TensorFileError(f"{path} is not an aes-planner tensor file (.npz); it is damaged or another format")
    try:
        with np.load(path, allow_pickle=False) as npz:
            names = npz.zip.namelist()
            if any(n == "data.pkl" or n.endswith("/data.pkl") for n in names):
                raise LegacyTorchFileError(_legacy(path))
            return _read(npz, path, max_bytes)
    except TensorFileError:
        raise
    except Exception as exc:  # zipfile/zlib/numpy errors on damaged bytes (BadZipFile, EOFError, ValueError, ...)
        text = " ".join(str(exc).split())[:160]
        raise TensorFileError(f"{path} is not a readable tensor file ({type(exc).__name__}: {text})") from None


def read_npz(path: str | Path, *, max_bytes: int = MAX_BYTES) -> dict[str, np.ndarray]:
    """Every array of a plain ``.npz`` (``np.savez``), each header checked before its data is read:
    numeric dtype (nothing unpickled), its declared size within what is left of ``max_bytes`` and
    within what its zip entry says it holds. A file that declares a huge array (an "npz bomb") or
    is damaged is a :class:`TensorFileError` naming it, before anything large is allocated."""
    path = Path(path)
    if not path.is_file():
        raise TensorFileError(f"{path} does not exist" + (" (it is a folder)" if path.is_dir() else ""))
    try:
        with np.load(path, allow_pickle=False) as npz:
            infos = {i.filename: i for i in npz.zip.infolist()}
            out, budget = {}, max_bytes
            for name in npz.files:
                arr = _array(npz, name, path, min(budget, infos[name + ".npy"].file_size), f"array {name!r}")
                budget -= arr.nbytes
                out[name] = arr
            return out
    except TensorFileError:
        raise
    except Exception as exc:  # zipfile/zlib/numpy errors on damaged bytes (BadZipFile, EOFError, ValueError, ...)
        text = " ".join(str(exc).split())[:160]
        raise TensorFileError(f"{path} is not a readable .npz ({type(exc).__name__}: {text})") from None


def _legacy(path: Path) -> str:
    return f"{path} was written by an older aes-planner in torch's pickle-based format, which is never loaded"


def _read(npz, path: Path, max_bytes: int) -> Any:
    entries = {n[: -len(".npy")] for n in npz.zip.namelist() if n.endswith(".npy")}
    if _TREE not in entries:
        raise TensorFileError(f"{path} is an .npz without an aes-planner tree ({_TREE}); not written by aes-planner")
    if len(entries) > MAX_ARRAYS + 1:
        raise TensorFileError(f"{path} holds {len(entries) - 1} arrays, more than {MAX_ARRAYS}")
    raw = _array(npz, _TREE, path, MAX_JSON_BYTES, "the JSON description")
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise TensorFileError(f"{path}: {_TREE} must be 1-D uint8 (UTF-8 JSON), got {raw.dtype} {raw.shape}")
    try:
        doc = json.loads(raw.tobytes().decode("utf-8"), parse_constant=_no_constant)
    except (ValueError, RecursionError) as exc:
        raise TensorFileError(f"{path}: its JSON description is damaged ({str(exc)[:120]})") from None
    if not (isinstance(doc, dict) and doc.get("format") == FORMAT and set(doc) == {"format", "version", "tree"}):
        raise TensorFileError(f"{path}: its JSON description is not an aes-planner tensor file's")
    if doc["version"] != VERSION:
        raise TensorFileError(f"{path}: tensor file version {doc['version']!r}; this aes-planner reads {VERSION}")
    state = {"entries": entries, "used": set(), "budget": max_bytes}
    tree = _build(doc["tree"], npz, path, state, "tree", 0)
    extra = entries - state["used"] - {_TREE}
    if extra:
        raise TensorFileError(f"{path} holds arrays its description does not name: {sorted(extra)[:5]}")
    return tree


def _no_constant(name: str):
    raise ValueError(f"{name} is not JSON")


def _build(node: Any, npz, path: Path, state: dict, where: str, depth: int) -> Any:
    if depth > MAX_DEPTH:
        raise TensorFileError(f"{path}: {where} is nested deeper than {MAX_DEPTH} levels")
    if node is None or isinstance(node, (bool, int, str)):
        return node
    if isinstance(node, float):
        if not math.isfinite(node):
            raise TensorFileError(f"{path}: {where} is a non-finite plain number")
        return node
    if not (isinstance(node, dict) and len(node) == 1):
        raise TensorFileError(f"{path}: {where} is not a known node (an object with one tag)")
    (tag, value), deeper = next(iter(node.items())), depth + 1
    if tag in ("tensor", "ndarray"):
        if not isinstance(value, str) or value not in state["entries"] or value == _TREE:
            raise TensorFileError(f"{path}: {where} names the array {str(value)[:40]!r}, which is not in the file")
        if value in state["used"]:
            raise TensorFileError(f"{path}: {where} names the array {value!r} a second time")
        state["used"].add(value)
        arr = _array(npz, value, path, state["budget"], where)
        state["budget"] -= arr.nbytes
        if tag == "ndarray":
            return arr
        if arr.dtype not in _TORCH_DTYPES:
            raise TensorFileError(f"{path}: {where} is a tensor of dtype {arr.dtype}, which this format does not store")
        return torch.from_numpy(arr)
    if tag in ("list", "tuple") and isinstance(value, list):
        items = [_build(v, npz, path, state, f"{where}[{i}]", deeper) for i, v in enumerate(value)]
        return items if tag == "list" else tuple(items)
    if tag == "dict" and isinstance(value, list):
        out: dict = {}
        for pair in value:
            if not (isinstance(pair, list) and len(pair) == 2):
                raise TensorFileError(f"{path}: {where} has a dict entry that is not a [key, value] pair")
            k = pair[0]
            if not (isinstance(k, str) or (isinstance(k, int) and not isinstance(k, bool))) or k in out:
                raise TensorFileError(f"{path}: {where} has a bad or repeated key {str(k)[:40]!r}")
            out[k] = _build(pair[1], npz, path, state, f"{where}[{k!r}]", deeper)
        return out
    if tag == "float" and value in _NONFINITE:
        return _NONFINITE[value]
    raise TensorFileError(f"{path}: {where} has the unknown tag {str(tag)[:40]!r}")


def _array(npz, name: str, path: Path, budget: int, what: str) -> np.ndarray:
    """The array ``name``, its header checked (numeric dtype, size within ``budget``) before its
    data is read; a native-byte-order, writable, C-contiguous copy."""
    fmt = np.lib.format
    with npz.zip.open(name + ".npy") as f:
        version = fmt.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = fmt.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = fmt.read_array_header_2_0(f)
        else:
            raise TensorFileError(f"{path}: {what} ({name}) uses .npy version {version}, which is not read")
    if dtype.hasobject or dtype.newbyteorder("=") not in _DTYPES:
        raise TensorFileError(f"{path}: {what} ({name}) has dtype {dtype}; only numeric arrays are read")
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes > budget:
        raise TensorFileError(f"{path}: {what} ({name}) of shape {shape} exceeds the size limit ({budget} bytes left)")
    arr = npz[name]
    return np.array(arr, dtype=arr.dtype.newbyteorder("="), order="C", copy=True)
