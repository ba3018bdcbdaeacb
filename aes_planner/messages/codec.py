"""The wire format of every message: a small self-describing header, then fixed fields and raw
little-endian arrays. No pickle, nothing executable, every length checked before it is used.

Layout (all integers little-endian)::

    offset  size  field
    0       4     magic b"AESM"
    4       1     format version (1)
    5       1     n = length of the type name (1..64)
    6       2     schema version of that type (uint16)
    8       4     payload length in bytes (uint32)
    12      n     type name, ASCII (``"PosedFrame"``)
    12+n    ...   payload: the type's fields in a fixed order

Payload primitives: ``u8/u32/u64/i64`` integers, ``f64`` floats, ``str`` (uint16 byte length +
UTF-8), ``opt`` (one flag byte 0/1, then the value when 1) and arrays: a dtype code byte
(``u1``, ``f4``, ``f8``), the number of dimensions, each dimension as uint32, then the raw
little-endian C-order data. A reader checks the dtype and the dimensions against what the field
expects, the byte count against what is left, and floats for NaN/Inf. Every failure raises
:class:`MessageError` with the reason; a buffer that decodes must be consumed exactly (no
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
    "decode",
    "peek_header",
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

    def __init__(self, data: bytes | memoryview, type_name: str) -> None:
        self._mv = memoryview(data)
        self._pos = 0
        self._type = type_name

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
    payload layout changes; a reader refuses versions it does not know), ``MAX_BYTES`` (the cap on
    the encoded size) and implement ``_write(w)`` and ``_read(r, version)``.
    """

    TYPE_NAME: ClassVar[str] = ""
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 1 << 20

    def _write(self, w: Writer, **options) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def _read(cls, r: Reader, version: int) -> Message:  # pragma: no cover - abstract
        raise NotImplementedError

    def encode(self, **options) -> bytes:
        return encode(self, **options)


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


def decode(data: bytes | bytearray | memoryview, expected: type[Message] | None = None, max_bytes: int | None = None):
    """Decode one message, checking everything; raise :class:`MessageError` with the reason.

    ``expected``: refuse any other type. ``max_bytes``: a tighter cap than the type's own.
    Never returns a message with NaN/Inf, and never raises anything but :class:`MessageError`.
    """
    header = peek_header(data)
    cls = message_type(header.type_name)
    if expected is not None and cls is not expected:
        raise MessageError(f"expected a {expected.TYPE_NAME} message, got {header.type_name}")
    if header.schema_version != cls.SCHEMA_VERSION:
        raise MessageError(
            f"{cls.TYPE_NAME} schema version {header.schema_version} is not supported (this build reads "
            f"version {cls.SCHEMA_VERSION}); run the same aes-planner version on every machine"
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
    r = Reader(memoryview(data)[start:], cls.TYPE_NAME)
    try:
        msg = cls._read(r, header.schema_version)
        r.finish()
    except MessageError:
        raise
    except (AesPlannerError, ValueError, TypeError, OverflowError, struct.error) as exc:
        # Field validation of the constructed message (intrinsics, poses...) uses other error types.
        raise MessageError(f"{cls.TYPE_NAME}: {exc}") from None
    return msg
