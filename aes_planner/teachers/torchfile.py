"""The sizes a ``torch.save`` file declares, read without unpickling, checked before ``torch.load``.

``torch.load`` allocates every storage at the size its pickle declares *before* it reads the data:
a 200-byte legacy file that declares an 800-million-element storage allocates 3.2 GB, then fails.
:func:`check_declared_sizes` reads the pickle's opcodes with :mod:`pickletools` (a listing: no
object is built, no class looked up, nothing run), collects the storages it declares and refuses
the file unless each fits in the bytes that hold it:

- zip format (torch >= 1.6): storage ``KEY`` is the record ``*/data/KEY``; its declared size must
  not exceed the record's;
- legacy format (torch < 1.6, e.g. VEN's released ``EvaluationNet.pth.tar``): five pickles, then
  the storages' data; their total declared size must not exceed the bytes after the pickles;
- the older tar format stores sizes torch reads and allocates on the fly: refused.

This is the same rule as the ``.npy`` header check of :mod:`aes_planner.tensorfile`.
"""

from __future__ import annotations

import io
import mmap
import pickletools
import tarfile
import zipfile
from pathlib import Path

__all__ = ["MAX_PICKLE_BYTES", "MAX_STORAGES", "DeclaredSizeError", "check_declared_sizes"]

#: Largest pickle (the file's structure, not its data) read: a VEN checkpoint's is a few kB.
MAX_PICKLE_BYTES = 64 << 20
#: Most storages a file may declare (VEN has 32 tensors).
MAX_STORAGES = 100_000
#: Bytes per element of torch's legacy typed storages (``torch.FloatStorage`` ...); others: 8.
_ELEMENT_BYTES = {
    "DoubleStorage": 8,
    "LongStorage": 8,
    "ComplexFloatStorage": 8,
    "ComplexDoubleStorage": 16,
    "FloatStorage": 4,
    "IntStorage": 4,
    "HalfStorage": 2,
    "BFloat16Storage": 2,
    "ShortStorage": 2,
    "CharStorage": 1,
    "ByteStorage": 1,
    "BoolStorage": 1,
    "UntypedStorage": 1,
}
_MARK = object()
_UNKNOWN = object()


class DeclaredSizeError(ValueError):
    """The file declares more than it holds, or cannot be listed (the caller words the advice)."""


def _persistent_ids(stream) -> list:
    """The persistent ids (``BINPERSID``/``PERSID`` arguments) of one pickle in ``stream``, found by
    a symbolic run of its opcodes: literals and tuples are tracked, everything else is opaque."""
    stack: list = []
    memo: dict = {}
    found: list = []

    def pop():
        if not stack:
            raise DeclaredSizeError("the pickle pops an empty stack")
        return stack.pop()

    def pop_mark() -> list:
        items = []
        while True:
            v = pop()
            if v is _MARK:
                return items[::-1]
            items.append(v)

    for op, arg, _ in pickletools.genops(stream):
        name, before, after = op.name, op.stack_before, op.stack_after
        if name == "MARK":
            stack.append(_MARK)
        elif name in ("PUT", "BINPUT", "LONG_BINPUT"):
            memo[arg] = stack[-1] if stack else _UNKNOWN
        elif name == "MEMOIZE":
            memo[len(memo)] = stack[-1] if stack else _UNKNOWN
        elif name in ("GET", "BINGET", "LONG_BINGET"):
            if arg not in memo:
                raise DeclaredSizeError(f"the pickle reads memo {arg}, which it never wrote")
            stack.append(memo[arg])
        elif name == "GLOBAL":
            stack.append(("global", str(arg)))
        elif name == "STACK_GLOBAL":
            qual, module = pop(), pop()
            stack.append(("global", f"{module} {qual}"))
        elif name == "TUPLE":
            stack.append(tuple(pop_mark()))
        elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
            n = int(name[-1])
            items = [pop() for _ in range(n)][::-1]
            stack.append(tuple(items))
        elif name == "EMPTY_TUPLE":
            stack.append(())
        elif name == "DUP":
            stack.append(stack[-1] if stack else _UNKNOWN)
        elif name in ("BINPERSID", "PERSID"):
            found.append(pop() if name == "BINPERSID" else arg)
            stack.append(_UNKNOWN)
        elif not before and len(after) == 1 and name not in ("EXT1", "EXT2", "EXT4"):
            stack.append(arg)  # a literal (int, string, None; containers as None: opaque)
        else:
            if pickletools.markobject in before:
                pop_mark()
                for _ in range(before.index(pickletools.markobject)):
                    pop()
            else:
                for _ in before:
                    pop()
            stack.extend(_UNKNOWN for _ in after)
        if len(found) > MAX_STORAGES:
            raise DeclaredSizeError(f"more than {MAX_STORAGES} storages")
    return found


def _storages(ids: list, legacy: bool) -> dict[str, int]:
    """``{key: declared bytes}`` of the storage ids (``('storage', class, key, location, numel[, view])``)."""
    out: dict[str, int] = {}
    for pid in ids:
        if not (isinstance(pid, tuple) and pid and pid[0] == "storage"):
            raise DeclaredSizeError(f"a persistent id that is not a storage: {str(pid)[:80]}")
        if len(pid) != (6 if legacy else 5):
            raise DeclaredSizeError(f"a storage id of {len(pid)} fields")
        cls, key, numel = pid[1], pid[2], pid[4]
        if not (isinstance(numel, int) and not isinstance(numel, bool) and numel >= 0) or not isinstance(key, str):
            raise DeclaredSizeError(f"storage {str(key)[:40]!r} declares the size {str(numel)[:40]}")
        cls_name = cls[1].rpartition(" ")[2] if isinstance(cls, tuple) and len(cls) == 2 else ""
        nbytes = numel * _ELEMENT_BYTES.get(cls_name, 8)
        out[key] = max(out.get(key, 0), nbytes)
    return out


def check_declared_sizes(path: Path) -> None:
    """Raise :class:`DeclaredSizeError` unless every storage ``path`` declares fits in the bytes
    that hold it (module docstring). Reads the file's structure only; bounded memory."""
    size = path.stat().st_size
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
            pickles = [i for i in infos if i.filename.endswith("data.pkl") and i.filename.count("/") == 1]
            if len(pickles) != 1:
                raise DeclaredSizeError(
                    f"a zip archive with {len(pickles)} '*/data.pkl' records (torch.save writes one)"
                )
            info = pickles[0]
            if info.file_size > MAX_PICKLE_BYTES:
                raise DeclaredSizeError(f"its pickle declares {info.file_size} bytes (at most {MAX_PICKLE_BYTES})")
            prefix = info.filename[: -len("data.pkl")]
            records = {
                i.filename[len(prefix) + 5 :]: i.file_size for i in infos if i.filename.startswith(prefix + "data/")
            }
            declared = _storages(_persistent_ids(io.BytesIO(z.read(info))), legacy=False)
        for key, nbytes in declared.items():
            if key not in records:
                raise DeclaredSizeError(f"storage {key[:40]!r} has no data record")
            if nbytes > records[key]:
                raise DeclaredSizeError(
                    f"storage {key[:40]!r} declares {nbytes} bytes; its record holds {records[key]}"
                )
        return
    if size == 0:
        raise DeclaredSizeError("an empty file")
    if tarfile.is_tarfile(path):
        raise DeclaredSizeError("a tar archive (PyTorch's pre-0.4 format, whose sizes are read as it loads)")
    with path.open("rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        # mmap.read(n) returns what is there: a length field of 4 GB allocates nothing.
        for _ in range(3):  # magic number, protocol version, system info
            _persistent_ids(mm)
        declared = _storages(_persistent_ids(mm), legacy=True)
        _persistent_ids(mm)  # the storage keys
        left = size - mm.tell()
    total = sum(declared.values())
    if total > left:
        raise DeclaredSizeError(f"its storages declare {total} bytes; the file holds {left} after its structure")
