"""The wire format of every message: a small self-describing header, then the type's fields in the
order of its field table. No pickle, nothing executable, every length checked before it is used.
The full specification, for readers in other languages, is ``docs/wire.md``.

Layout (all integers little-endian)::

    offset  size  field
    0       4     magic b"AESM"
    4       1     format version (1)
    5       1     n = length of the type name (1..64)
    6       2     schema version of that type (uint16)
    8       4     payload length in bytes (uint32)
    12      n     type name, ASCII (``"PosedFrame"``)
    12+n    ...   payload: the type's fields in a fixed order

Each message type declares its fields once, in ``FIELDS`` (a tuple of :class:`Field`:
:class:`Scalar` ``u8/u16/u32/u64/i64/f64/bool``, :class:`Str` (uint16 byte length + UTF-8),
:class:`Bytes`, :class:`Enum` (a code byte), :class:`Array` (dtype code byte ``1`` u1, ``2`` f4,
``3`` f8, the number of dimensions, each dimension as uint32, then the raw little-endian C-order
data), :class:`Optional` (a flag byte 0/1, then the value), :class:`List` (a u8 or u32 count),
:class:`Fixed`, :class:`Map`, :class:`Struct`, :class:`Union` (a tag byte, then the variant's
fields)). That table drives :func:`encode`, :func:`decode`, :func:`describe` (the JSON layout a
recording carries) and ``to_jsonable``. A reader checks the dtype and the dimensions against what
the field expects, the byte count against what is left, and floats for NaN/Inf. Every failure
raises :class:`MessageError` with the reason; a buffer that decodes must be consumed exactly (no
trailing bytes).
"""

from __future__ import annotations

import math
import struct
from typing import ClassVar

import numpy as np

from aes_planner.errors import AesPlannerError

__all__ = [
    "MAGIC",
    "FORMAT_VERSION",
    "HEADER_SIZE",
    "MessageError",
    "Message",
    "Reader",
    "Writer",
    "Header",
    "MESSAGE_TYPES",
    "register_message",
    "message_type",
    "encode",
    "check_envelope",
    "decode",
    "peek_header",
    "describe",
    "text_cap",
    "Field",
    "Scalar",
    "Str",
    "Bytes",
    "Enum",
    "Array",
    "Optional",
    "Fixed",
    "List",
    "Map",
    "Struct",
    "Union",
]

MAGIC = b"AESM"
FORMAT_VERSION = 1
_HEADER = struct.Struct("<4sBBHI")
HEADER_SIZE = _HEADER.size  # 12, then the type name
MAX_NAME_LEN = 64
MAX_STRING_BYTES = 4096

_DTYPES = {1: np.dtype("<u1"), 2: np.dtype("<f4"), 3: np.dtype("<f8")}
_DTYPE_CODES = {dt: code for code, dt in _DTYPES.items()}


class MessageError(AesPlannerError, ValueError):
    """A message field has the wrong shape, type or a non-finite value, or bytes do not decode."""


class Writer:
    """Appends payload fields; :meth:`getvalue` joins them."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []
        self.size = 0

    def _add(self, b: bytes) -> None:
        self._parts.append(b)
        self.size += len(b)

    def u8(self, v: int) -> None:
        self._add(struct.pack("<B", v))

    def u32(self, v: int) -> None:
        self._add(struct.pack("<I", v))

    def u64(self, v: int) -> None:
        self._add(struct.pack("<Q", v))

    def i64(self, v: int) -> None:
        self._add(struct.pack("<q", v))

    def f64(self, v: float) -> None:
        self._add(struct.pack("<d", v))

    def bool(self, v: bool) -> None:
        self.u8(1 if v else 0)

    def str(self, v: str) -> None:
        b = v.encode("utf-8")
        if len(b) > MAX_STRING_BYTES:
            raise MessageError(f"string of {len(b)} bytes exceeds the {MAX_STRING_BYTES}-byte cap")
        self._add(struct.pack("<H", len(b)))
        self._add(b)

    def opt_f64(self, v: float | None) -> None:
        self.bool(v is not None)
        if v is not None:
            self.f64(v)

    def array(self, a: np.ndarray, dtype: str) -> None:
        dt = np.dtype(dtype).newbyteorder("<")
        a = np.ascontiguousarray(a, dtype=dt)
        self.u8(_DTYPE_CODES[dt])
        self.u8(a.ndim)
        for d in a.shape:
            self.u32(d)
        self._add(a.tobytes())

    def raw(self, b: bytes) -> None:
        self.u32(len(b))
        self._add(bytes(b))

    def getvalue(self) -> bytes:
        return b"".join(self._parts)


class Reader:
    """Reads payload fields, checking every length against what is left."""

    def __init__(self, data: bytes | memoryview, type_name: str, version: int = 1) -> None:
        self._mv = memoryview(data)
        self._pos = 0
        self._type = type_name
        self.version = version  # the schema version of the message being read

    def _take(self, n: int, what: str) -> memoryview:
        if n < 0 or self._pos + n > len(self._mv):
            raise MessageError(
                f"{self._type}: truncated payload reading {what} "
                f"(needs {n} bytes at offset {self._pos}, {len(self._mv) - self._pos} left)"
            )
        out = self._mv[self._pos : self._pos + n]
        self._pos += n
        return out

    def u8(self, what: str) -> int:
        return self._take(1, what)[0]

    def u32(self, what: str) -> int:
        return struct.unpack("<I", self._take(4, what))[0]

    def u64(self, what: str) -> int:
        return struct.unpack("<Q", self._take(8, what))[0]

    def i64(self, what: str) -> int:
        return struct.unpack("<q", self._take(8, what))[0]

    def f64(self, what: str) -> float:
        v = struct.unpack("<d", self._take(8, what))[0]
        if not math.isfinite(v):
            raise MessageError(f"{self._type}.{what} is {v}; every number must be finite")
        return v

    def bool(self, what: str) -> bool:
        v = self.u8(what)
        if v > 1:
            raise MessageError(f"{self._type}.{what}: flag byte must be 0 or 1, got {v}")
        return v == 1

    def str(self, what: str, max_len: int = MAX_STRING_BYTES) -> str:
        n = struct.unpack("<H", self._take(2, what))[0]
        if n > max_len:
            raise MessageError(f"{self._type}.{what}: string of {n} bytes exceeds the cap of {max_len}")
        try:
            return bytes(self._take(n, what)).decode("utf-8")
        except UnicodeDecodeError:
            raise MessageError(f"{self._type}.{what}: not valid UTF-8") from None

    def opt_f64(self, what: str) -> float | None:
        return self.f64(what) if self.bool(what) else None

    def array(self, what: str, dtype: str, ndim: int, max_dims: tuple[int, ...]) -> np.ndarray:
        """An array of ``dtype`` with ``ndim`` dimensions, each at most ``max_dims[i]``
        (``-1`` in ``max_dims`` is not allowed: give a real cap). Floats are checked finite."""
        code = self.u8(what)
        expected = np.dtype(dtype).newbyteorder("<")
        dt = _DTYPES.get(code)
        if dt is None or dt != expected:
            got = dt.str if dt is not None else f"unknown dtype code {code}"
            raise MessageError(f"{self._type}.{what}: expected dtype {expected.str}, got {got}")
        nd = self.u8(what)
        if nd != ndim:
            raise MessageError(f"{self._type}.{what}: expected {ndim} dimensions, got {nd}")
        shape = tuple(self.u32(what) for _ in range(nd))
        for d, cap in zip(shape, max_dims):
            if d > cap:
                raise MessageError(f"{self._type}.{what}: shape {shape} exceeds the cap {max_dims}")
        count = math.prod(shape)
        buf = self._take(count * dt.itemsize, what)
        a = np.frombuffer(buf, dtype=dt).reshape(shape).astype(dt.newbyteorder("="), copy=True)
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise MessageError(f"{self._type}.{what}: contains NaN or Inf; every number must be finite")
        return a

    def raw(self, what: str, max_len: int) -> bytes:
        n = self.u32(what)
        if n > max_len:
            raise MessageError(f"{self._type}.{what}: {n} bytes exceed the cap of {max_len}")
        return bytes(self._take(n, what))

    def finish(self) -> None:
        left = len(self._mv) - self._pos
        if left:
            raise MessageError(f"{self._type}: {left} trailing bytes after the last field (a newer or corrupt message)")


class Message:
    """Base of every message type: a dataclass that validates itself on construction.

    Subclasses set ``TYPE_NAME`` (the name in the header), ``SCHEMA_VERSION`` (bumped when the
    payload layout changes, see :data:`FIELDS`), ``MAX_BYTES`` (the cap on the encoded size) and
    ``FIELDS``: the type's field table, the one place its wire layout is declared. Encoding,
    decoding, :func:`describe` (the machine-readable layout a recording carries) and
    :func:`aes_planner.messages.to_jsonable` all follow it.

    Versioning: a field added in version N is appended at the end of ``FIELDS`` with
    ``since=N`` and a default, and ``SCHEMA_VERSION`` becomes N. A message of an older version
    decodes (the newer fields take their defaults); a newer one is refused.
    """

    TYPE_NAME: ClassVar[str] = ""
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 1 << 20
    FIELDS: ClassVar[tuple[Field, ...]] = ()
    OPTIONS: ClassVar[tuple[str, ...]] = ()  # keyword options encode() takes for this type

    def _write(self, w: Writer, **options) -> None:
        write_fields(w, self, self.FIELDS, options)

    @classmethod
    def _read(cls, r: Reader, version: int) -> Message:
        return cls._from_wire(read_fields(r, cls.FIELDS, version, ""), version)

    @classmethod
    def _from_wire(cls, values: dict, version: int) -> Message:
        """The message from its decoded field values (by field name); types whose fields are not
        their constructor's arguments override this."""
        return cls(**values)

    def encode(self, **options) -> bytes:
        return encode(self, **options)


# -- the field table --------------------------------------------------------------------------

_SCALARS = {"u8": "<B", "u16": "<H", "u32": "<I", "u64": "<Q", "i64": "<q", "f64": "<d"}


class Field:
    """One field of a message on the wire: its ``name``, how it is written and read, and its
    description (:meth:`describe`). ``since``: the schema version that added it (older messages
    lack it and decode to ``default``). ``attr``: the attribute it is read from when encoding,
    dotted for a nested one (``intrinsics.fx``); the name by default. ``doc``: what it means, the
    note docs/wire.md shows beside it."""

    def __init__(self, name: str, *, since: int = 1, default=None, attr: str | None = None, doc: str = "") -> None:
        self.name = name
        self.since = since
        self.default = default
        self.attr = attr or name
        self.doc = doc  # what the field means: docs/wire.md's note, rendered by aes_planner.messages.spec

    def value_of(self, msg, options: dict):
        v = msg
        for part in self.attr.split("."):
            v = getattr(v, part)
        return v

    def write(self, w: Writer, value, options: dict) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def read(self, r: Reader, what: str):  # pragma: no cover - abstract
        raise NotImplementedError

    def kind(self) -> dict:  # pragma: no cover - abstract
        """The JSON description of the field's type (docs/wire.md, "Type descriptions")."""
        raise NotImplementedError

    def describe(self) -> dict:
        out = {"name": self.name, **self.kind()}
        if self.since > 1:
            out["since"] = self.since
            out["default"] = self.default
        return out

    def json(self, value):
        """The field's value as JSON (numbers, strings, lists, dicts)."""
        return value


class Scalar(Field):
    """``u8/u16/u32/u64/i64`` integers, ``f64`` (finite), ``bool`` (a byte 0 or 1)."""

    def __init__(self, name: str, fmt: str, **kw) -> None:
        super().__init__(name, **kw)
        if fmt not in _SCALARS and fmt != "bool":
            raise ValueError(f"unknown scalar {fmt!r}")
        self.fmt = fmt

    def write(self, w, value, options) -> None:
        if self.fmt == "bool":
            w.bool(value)
        else:
            w._add(struct.pack(_SCALARS[self.fmt], value))

    def read(self, r, what):
        if self.fmt == "bool":
            return r.bool(what)
        if self.fmt == "f64":
            return r.f64(what)
        fmt = _SCALARS[self.fmt]
        return struct.unpack(fmt, r._take(struct.calcsize(fmt), what))[0]

    def kind(self) -> dict:
        return {"type": self.fmt}


class Str(Field):
    """UTF-8 text: a uint16 byte length, then the bytes; a reader refuses more than ``max_bytes``."""

    def __init__(self, name: str, max_bytes: int = MAX_STRING_BYTES, **kw) -> None:
        super().__init__(name, **kw)
        self.max_bytes = max_bytes

    def write(self, w, value, options) -> None:
        if len(value.encode("utf-8")) > self.max_bytes:  # never write what a reader refuses
            raise MessageError(f"{self.name}: {len(value.encode('utf-8'))} bytes of UTF-8; the cap is {self.max_bytes}")
        w.str(value)

    def read(self, r, what):
        return r.str(what, self.max_bytes)

    def kind(self) -> dict:
        return {"type": "str", "max_bytes": self.max_bytes}


class Bytes(Field):
    """Raw bytes: a uint32 length, then the bytes (at most ``max_bytes``)."""

    def __init__(self, name: str, max_bytes: int, **kw) -> None:
        super().__init__(name, **kw)
        self.max_bytes = max_bytes

    def write(self, w, value, options) -> None:
        w.raw(value)

    def read(self, r, what):
        return r.raw(what, self.max_bytes)

    def kind(self) -> dict:
        return {"type": "bytes", "max_bytes": self.max_bytes}


class Enum(Field):
    """One of ``values`` (strings), written as its index in one byte."""

    def __init__(self, name: str, values: tuple[str, ...], type_name: str = "", **kw) -> None:
        super().__init__(name, **kw)
        self.values = tuple(values)
        self.type_name = type_name

    def write(self, w, value, options) -> None:
        w.u8(self.values.index(value))

    def read(self, r, what):
        code = r.u8(what)
        if code >= len(self.values):
            raise MessageError(f"{self.type_name or r._type}.{what} code {code} unknown (known: {list(self.values)})")
        return self.values[code]

    def kind(self) -> dict:
        return {"type": "enum", "values": list(self.values)}


class Array(Field):
    """A numpy array: dtype code byte, ndim byte, each dimension as uint32 (at most
    ``max_shape``), then the raw little-endian C-order data. Floats must be finite. ``exact``: the
    dimensions that must equal ``max_shape`` rather than stay under it (True: all of them, for a
    ``[4, 4]`` pose; a tuple of flags per dimension, for an image's 3 channels)."""

    def __init__(self, name: str, dtype: str, max_shape: tuple[int, ...], exact: bool | tuple[bool, ...] = False, **kw):
        super().__init__(name, **kw)
        self.dtype = dtype
        self.max_shape = tuple(max_shape)
        self.exact = tuple(exact) if isinstance(exact, tuple) else (bool(exact),) * len(self.max_shape)
        if len(self.exact) != len(self.max_shape):
            raise ValueError(f"{name}: exact needs one flag per dimension of {self.max_shape}")

    def write(self, w, value, options) -> None:
        w.array(value, self.dtype)

    def read(self, r, what):
        a = r.array(what, self.dtype, len(self.max_shape), self.max_shape)
        if any(e and n != cap for n, cap, e in zip(a.shape, self.max_shape, self.exact)):
            want = ", ".join(str(c) if e else f"<= {c}" for c, e in zip(self.max_shape, self.exact))
            raise MessageError(f"{r._type}.{what}: shape {a.shape}, expected [{want}]")
        return a

    def kind(self) -> dict:
        out = {"type": "array", "dtype": self.dtype, "ndim": len(self.max_shape), "max_shape": list(self.max_shape)}
        if any(self.exact):
            out["exact"] = list(self.exact)
        return out

    def json(self, value):
        if value.size <= 64:
            return value.tolist()
        return {  # summarised: echo prints messages, not megabytes
            "shape": list(value.shape),
            "mean": float(value.mean()),
            "max": float(value.max()),
            "nonzero": float((value != 0).mean()),
        }


class Optional(Field):
    """A flag byte (0 absent, 1 present), then the value when present. Absent is ``None``."""

    def __init__(self, inner: Field, **kw) -> None:
        kw.setdefault("doc", inner.doc)
        super().__init__(inner.name, attr=inner.attr, **kw)
        self.inner = inner

    def write(self, w, value, options) -> None:
        w.bool(value is not None)
        if value is not None:
            self.inner.write(w, value, options)

    def read(self, r, what):
        return self.inner.read(r, what) if r.bool(what) else None

    def kind(self) -> dict:
        return {"type": "optional", "value": self.inner.kind()}

    def json(self, value):
        return None if value is None else self.inner.json(value)


class Fixed(Field):
    """Exactly ``n`` items one after another, no count (a pair of temperatures)."""

    def __init__(self, name: str, item: Field, n: int, **kw) -> None:
        super().__init__(name, **kw)
        self.item, self.n = item, n

    def write(self, w, value, options) -> None:
        for v in value:
            self.item.write(w, v, options)

    def read(self, r, what):
        return tuple(self.item.read(r, f"{what}[{i}]") for i in range(self.n))

    def kind(self) -> dict:
        return {"type": "fixed", "n": self.n, "items": self.item.kind()}

    def json(self, value):
        return [self.item.json(v) for v in value]


class List(Field):
    """A count (``u8`` or ``u32``, at most ``max_count``), then that many items."""

    def __init__(self, name: str, item: Field, count: str, max_count: int, **kw) -> None:
        super().__init__(name, **kw)
        self.item, self.count, self.max_count = item, count, max_count

    def write(self, w, value, options) -> None:
        (w.u8 if self.count == "u8" else w.u32)(len(value))
        for v in value:
            self.item.write(w, v, options)

    def read(self, r, what):
        n = r.u8(what) if self.count == "u8" else r.u32(what)
        if n > self.max_count:
            raise MessageError(f"{r._type}.{what}: {n} items exceed the cap of {self.max_count}")
        return [self.item.read(r, f"{what}[{i}]") for i in range(n)]

    def kind(self) -> dict:
        return {"type": "list", "count": self.count, "max": self.max_count, "items": self.item.kind()}

    def json(self, value):
        return [self.item.json(v) for v in value]


class Map(Field):
    """A uint32 count (at most ``max_count``), then that many (key, value) pairs; keys are
    strings of at most 64 bytes."""

    KEY = Str("key", 64)

    def __init__(self, name: str, value: Field, max_count: int, **kw) -> None:
        super().__init__(name, **kw)
        self.value, self.max_count = value, max_count

    def write(self, w, value, options) -> None:
        w.u32(len(value))
        for k, v in value.items():
            w.str(k)
            self.value.write(w, v, options)

    def read(self, r, what):
        n = r.u32(what)
        if n > self.max_count:
            raise MessageError(f"{r._type}.{what}: {n} entries exceed the cap of {self.max_count}")
        out = {}
        for _ in range(n):
            key = self.KEY.read(r, f"{what} key")
            out[key] = self.value.read(r, f"{what}[{key!r}]")
        return out

    def kind(self) -> dict:
        return {"type": "map", "max": self.max_count, "key": self.KEY.kind(), "value": self.value.kind()}

    def json(self, value):
        return dict(value)


class Struct(Field):
    """A record with its own field table: ``cls.FIELDS`` one after another, built back with
    ``cls._from_wire(values, version)``."""

    def __init__(self, name: str, cls: type, **kw) -> None:
        super().__init__(name, **kw)
        self.cls = cls

    def write(self, w, value, options) -> None:
        write_fields(w, value, self.cls.FIELDS, options)

    def read(self, r, what):
        return self.cls._from_wire(read_fields(r, self.cls.FIELDS, r.version, what + "."), r.version)

    def kind(self) -> dict:
        return {"type": "struct", "name": self.cls.__name__, "fields": [f.describe() for f in self.cls.FIELDS]}

    def json(self, value):
        return fields_json(value, self.cls.FIELDS)


class Union(Field):
    """A tag byte, then the fields of the variant it names: ``variants`` maps each tag to a
    ``(variant name, fields)``. :meth:`to_wire` / :meth:`from_wire` convert the attribute to and
    from ``(tag, {field: value})``; subclasses implement them."""

    def __init__(self, name: str, variants: dict[int, tuple[str, tuple[Field, ...]]], **kw) -> None:
        super().__init__(name, **kw)
        self.variants = variants

    def to_wire(self, value, options: dict) -> tuple[int, dict]:  # pragma: no cover - abstract
        raise NotImplementedError

    def from_wire(self, tag: int, values: dict):  # pragma: no cover - abstract
        raise NotImplementedError

    def write(self, w, value, options) -> None:
        tag, values = self.to_wire(value, options)
        w.u8(tag)
        for f in self.variants[tag][1]:
            f.write(w, values[f.name], options)

    def read(self, r, what):
        tag = r.u8(what)
        if tag not in self.variants:
            raise MessageError(f"{r._type}: unknown {self.name} format code {tag} (known: {sorted(self.variants)})")
        fields = self.variants[tag][1]
        return self.from_wire(tag, {f.name: f.read(r, f"{what}.{f.name}") for f in fields})

    def kind(self) -> dict:
        return {
            "type": "union",
            "variants": {
                str(tag): {"name": name, "fields": [f.describe() for f in fields]}
                for tag, (name, fields) in sorted(self.variants.items())
            },
        }


def text_cap(fields: tuple[Field, ...], name: str) -> int:
    """The ``max_bytes`` of the text field ``name`` of a field table (a list's or an optional's
    text item too): the one cap the wire and the message's own validation apply."""
    for f in fields:
        if f.name == name:
            inner = getattr(f, "inner", None) or getattr(f, "item", None) or f
            if isinstance(inner, Str):
                return inner.max_bytes
    raise KeyError(f"no text field {name!r} in the table")


def write_fields(w: Writer, obj, fields: tuple[Field, ...], options: dict) -> None:
    for f in fields:
        f.write(w, f.value_of(obj, options), options)


def read_fields(r: Reader, fields: tuple[Field, ...], version: int, prefix: str) -> dict:
    """``{name: value}`` of ``fields`` as a message of schema ``version`` has them (later fields
    take their defaults)."""
    return {f.name: f.read(r, prefix + f.name) if f.since <= version else f.default for f in fields}


def fields_json(obj, fields: tuple[Field, ...]) -> dict:
    """``obj``'s fields as JSON by the table (a dotted name nests: ``intrinsics.fx`` ->
    ``{"intrinsics": {"fx": ...}}``), plus what its ``_json_extra()`` adds."""
    out: dict = {}
    for f in fields:
        *parents, leaf = f.name.split(".")
        node = out
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = f.json(f.value_of(obj, {}))
    extra = getattr(obj, "_json_extra", None)
    if extra is not None:
        out.update(extra())
    return out


def describe(cls: type[Message]) -> dict:
    """The machine-readable layout of ``cls`` (JSON-ready): what a recording's schema of the type
    holds, so a reader in any language can decode it (grammar in docs/wire.md)."""
    return {
        "encoding": "aes-planner",
        "format_version": FORMAT_VERSION,
        "doc": "docs/wire.md",
        "type": cls.TYPE_NAME,
        "schema_version": cls.SCHEMA_VERSION,
        "max_bytes": cls.MAX_BYTES,
        "header": {"magic": MAGIC.decode(), "layout": "<4sBBHI, then the type name (ASCII)"},
        "array_dtypes": {str(code): dt.str.lstrip("<|") for code, dt in _DTYPES.items()},
        "fields": [f.describe() for f in cls.FIELDS],
    }


MESSAGE_TYPES: dict[str, type[Message]] = {}


def register_message(cls: type[Message]) -> type[Message]:
    """Class decorator: make ``cls`` decodable by its ``TYPE_NAME``."""
    name = cls.TYPE_NAME
    if not name or len(name) > MAX_NAME_LEN or not name.isascii() or not name.isidentifier():
        raise ValueError(f"message TYPE_NAME must be an ASCII identifier of at most {MAX_NAME_LEN} chars, got {name!r}")
    MESSAGE_TYPES[name] = cls
    return cls


def message_type(name: str) -> type[Message]:
    """The message class registered under ``name``; :class:`MessageError` when unknown."""
    cls = MESSAGE_TYPES.get(name)
    if cls is None:
        raise MessageError(f"unknown message type {name!r}; known types: {', '.join(sorted(MESSAGE_TYPES))}")
    return cls


def encode(msg: Message, **options) -> bytes:
    """Header + payload bytes of ``msg``; :class:`MessageError` when over the type's size cap.

    ``options`` go to the type (``PosedFrame``: ``image_format="png"`` for recordings)."""
    cls = type(msg)
    if cls.TYPE_NAME not in MESSAGE_TYPES:
        raise MessageError(f"{cls.__name__} is not a registered message type")
    unknown = sorted(set(options) - set(cls.OPTIONS))
    if unknown:
        raise MessageError(f"{cls.TYPE_NAME} takes no encoding option {unknown[0]!r}; its options: {list(cls.OPTIONS)}")
    w = Writer()
    msg._write(w, **options)
    name = cls.TYPE_NAME.encode("ascii")
    total = HEADER_SIZE + len(name) + w.size
    if total > cls.MAX_BYTES:
        raise MessageError(f"{cls.TYPE_NAME}: encoded size {total} bytes exceeds the cap of {cls.MAX_BYTES}")
    return _HEADER.pack(MAGIC, FORMAT_VERSION, len(name), cls.SCHEMA_VERSION, w.size) + name + w.getvalue()


class Header(tuple):
    """``(type_name, schema_version, payload_len)`` of an encoded message."""

    __slots__ = ()

    def __new__(cls, type_name: str, schema_version: int, payload_len: int):
        return super().__new__(cls, (type_name, schema_version, payload_len))

    type_name = property(lambda self: self[0])
    schema_version = property(lambda self: self[1])
    payload_len = property(lambda self: self[2])


def peek_header(data: bytes | bytearray | memoryview) -> Header:
    """Parse and check the header only (no payload validation)."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"expected bytes, got {type(data).__name__}")
    if len(data) < HEADER_SIZE:
        raise MessageError(f"truncated header: {len(data)} bytes, a message starts with {HEADER_SIZE}")
    magic, fmt, name_len, version, payload_len = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise MessageError(f"not an aes-planner message (magic {bytes(magic)!r}, expected {MAGIC!r})")
    if fmt != FORMAT_VERSION:
        raise MessageError(f"wire format version {fmt} is not supported (this build reads {FORMAT_VERSION})")
    if not 1 <= name_len <= MAX_NAME_LEN:
        raise MessageError(f"type name length {name_len} out of range 1..{MAX_NAME_LEN}")
    if len(data) < HEADER_SIZE + name_len:
        raise MessageError("truncated header: the type name is cut off")
    try:
        name = bytes(data[HEADER_SIZE : HEADER_SIZE + name_len]).decode("ascii")
    except UnicodeDecodeError:
        raise MessageError("type name is not ASCII") from None
    if not name.isidentifier():
        raise MessageError(f"type name {name!r} is not an identifier")
    return Header(name, version, payload_len)


def check_envelope(
    data: bytes | bytearray | memoryview, expected: type[Message] | None = None, max_bytes: int | None = None
) -> tuple[type[Message], Header]:
    """Check everything but the payload's contents, in O(1): the header, the type (``expected``:
    refuse any other), its schema version, the size cap (``max_bytes``: tighter than the type's
    own) and that the payload is as long as the header says. Returns (the type, the header);
    raises :class:`MessageError` with the reason. A transport screens arriving samples with it
    before it queues them, so a sample that cannot decode never takes a good one's place."""
    header = peek_header(data)
    cls = message_type(header.type_name)
    if expected is not None and cls is not expected:
        raise MessageError(f"expected a {expected.TYPE_NAME} message, got {header.type_name}")
    if not 1 <= header.schema_version <= cls.SCHEMA_VERSION:
        raise MessageError(
            f"{cls.TYPE_NAME} schema version {header.schema_version} is not supported (this build reads "
            f"versions 1 to {cls.SCHEMA_VERSION}); a newer aes-planner wrote it: upgrade this one"
        )
    cap = cls.MAX_BYTES if max_bytes is None else min(max_bytes, cls.MAX_BYTES)
    start = HEADER_SIZE + len(header.type_name)
    if len(data) > cap:
        raise MessageError(f"{cls.TYPE_NAME}: {len(data)} bytes exceed the cap of {cap}")
    if len(data) - start != header.payload_len:
        raise MessageError(
            f"{cls.TYPE_NAME}: header says {header.payload_len} payload bytes, got {len(data) - start} "
            "(truncated or padded)"
        )
    return cls, header


def decode(data: bytes | bytearray | memoryview, expected: type[Message] | None = None, max_bytes: int | None = None):
    """Decode one message, checking everything; raise :class:`MessageError` with the reason.

    ``expected``: refuse any other type. ``max_bytes``: a tighter cap than the type's own.
    Never returns a message with NaN/Inf, and never raises anything but :class:`MessageError`.
    """
    cls, header = check_envelope(data, expected, max_bytes)
    start = HEADER_SIZE + len(header.type_name)
    r = Reader(memoryview(data)[start:], cls.TYPE_NAME, header.schema_version)
    try:
        msg = cls._read(r, header.schema_version)
        r.finish()
    except MessageError:
        raise
    except (AesPlannerError, ValueError, TypeError, OverflowError, struct.error) as exc:
        # Field validation of the constructed message (intrinsics, poses...) uses other error types.
        raise MessageError(f"{cls.TYPE_NAME}: {exc}") from None
    return msg
