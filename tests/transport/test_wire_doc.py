"""docs/wire.md holds: a decoder written from it alone (below: struct and numpy, no aes_planner import
in the decoder) decodes every message of a recording from the type descriptions the recording
carries, and gets the values the package encoded."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from mcap.reader import make_reader

# ------------------------------------------------------------------ the independent decoder
SCALARS = {"u8": "<B", "u16": "<H", "u32": "<I", "u64": "<Q", "i64": "<q", "f64": "<d"}
DTYPES = {"u1": "<u1", "f4": "<f4", "f8": "<f8"}


class WireError(Exception):
    pass


class Cursor:
    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def take(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise WireError(f"truncated at {self.pos} (+{n} of {len(self.data)})")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def scalar(self, name: str):
        fmt = SCALARS[name]
        return struct.unpack(fmt, self.take(struct.calcsize(fmt)))[0]


def read_value(c: Cursor, t: dict, dtype_codes: dict[int, str], version: int):
    kind = t["type"]
    if kind in SCALARS:
        v = c.scalar(kind)
        if kind == "f64" and not np.isfinite(v):
            raise WireError("non-finite")
        return v
    if kind == "bool":
        b = c.scalar("u8")
        if b > 1:
            raise WireError("bool byte")
        return b == 1
    if kind == "str":
        n = c.scalar("u16")
        if n > t["max_bytes"]:
            raise WireError("string too long")
        return c.take(n).decode("utf-8")
    if kind == "bytes":
        n = c.scalar("u32")
        if n > t["max_bytes"]:
            raise WireError("bytes too long")
        return c.take(n)
    if kind == "enum":
        return t["values"][c.scalar("u8")]
    if kind == "optional":
        return read_value(c, t["value"], dtype_codes, version) if c.scalar("u8") else None
    if kind == "array":
        dtype = dtype_codes[c.scalar("u8")]
        if dtype != t["dtype"] or c.scalar("u8") != t["ndim"]:
            raise WireError("array dtype or ndim")
        shape = tuple(c.scalar("u32") for _ in range(t["ndim"]))
        if any(d > m for d, m in zip(shape, t["max_shape"])):
            raise WireError("array too large")
        if any(e and d != m for d, m, e in zip(shape, t["max_shape"], t.get("exact", [False] * t["ndim"]))):
            raise WireError("array of another shape")
        dt = np.dtype(DTYPES[dtype])
        return np.frombuffer(c.take(int(np.prod(shape)) * dt.itemsize), dt).reshape(shape)
    if kind in ("list", "fixed"):
        n = t["n"] if kind == "fixed" else c.scalar(t["count"])
        if kind == "list" and n > t["max"]:
            raise WireError("list too long")
        return [read_value(c, t["items"], dtype_codes, version) for _ in range(n)]
    if kind == "map":
        n = c.scalar("u32")
        if n > t["max"]:
            raise WireError("map too long")
        return {
            read_value(c, t["key"], dtype_codes, version): read_value(c, t["value"], dtype_codes, version)
            for _ in range(n)
        }
    if kind == "struct":
        return read_fields(c, t["fields"], dtype_codes, version)
    if kind == "union":
        tag = c.scalar("u8")
        variant = t["variants"][str(tag)]
        return {"variant": variant["name"], **read_fields(c, variant["fields"], dtype_codes, version)}
    raise WireError(f"unknown type {kind}")


def read_fields(c: Cursor, fields: list[dict], dtype_codes, version: int) -> dict:
    out = {}
    for f in fields:
        if f.get("since", 1) <= version:
            out[f["name"]] = read_value(c, f, dtype_codes, version)
        else:
            out[f["name"]] = f["default"]
    return out


def decode_with(description: dict, data: bytes) -> dict:
    """One message: the header of docs/wire.md, then the fields the description lists."""
    magic, fmt, name_len, version, payload_len = struct.unpack_from("<4sBBHI", data, 0)
    name = data[12 : 12 + name_len].decode("ascii")
    if magic != b"AESM" or fmt != description["format_version"] or name != description["type"]:
        raise WireError(f"header {magic!r} {fmt} {name}")
    if version > description["schema_version"] or len(data) != 12 + name_len + payload_len:
        raise WireError("version or length")
    codes = {int(k): v for k, v in description["array_dtypes"].items()}
    c = Cursor(data[12 + name_len :])
    out = read_fields(c, description["fields"], codes, version)
    if c.pos != payload_len:
        raise WireError(f"{payload_len - c.pos} bytes left over")
    return {"type": name, "version": version, **out}


def decode_recording(path) -> list[tuple[str, dict]]:
    """Every ``aes-planner`` message of an MCAP file, decoded from its channel's schema alone."""
    out = []
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "aes-planner":
                continue
            assert schema.encoding == "aes-planner"
            out.append((channel.topic, decode_with(json.loads(schema.data), message.data)))
    return out


# -------------------------------------------------------------------------------- the tests
def _expected(obj, name: str):
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


def assert_matches(decoded: dict, msg, fields: list[dict]) -> None:
    """Every described field of ``decoded`` equals the attribute the package built."""
    import cv2

    for f in fields:
        got, want = decoded[f["name"]], _expected(msg, f["name"])
        if f["type"] == "union":  # the image: raw pixels, or a PNG of the same pixels
            if got["variant"] == "raw":
                assert np.array_equal(got["pixels"], want)
            else:
                png = got["png"]
                assert png[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", png[16:24]) == (
                    got["width"],
                    got["height"],
                )
                assert np.array_equal(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1], want)
        elif f["type"] == "optional" and f["value"]["type"] == "struct":  # a suggestion's explore candidate
            assert (got is None) == (want is None), f["name"]
            if want is not None:
                assert_matches(got, want, f["value"]["fields"])
        elif f["type"] == "list" and f["items"]["type"] == "struct":
            assert len(got) == len(want)
            for g, w in zip(got, want):
                assert_matches(g, w, f["items"]["fields"])
        elif f["type"] == "array" or (f["type"] == "optional" and f["value"]["type"] == "array" and want is not None):
            assert np.array_equal(got, want), f["name"]
        else:
            assert (list(got) if isinstance(want, tuple) else got) == (
                list(want) if isinstance(want, tuple) else want
            ), f["name"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Every message type on a bus into a recording, plus a PNG frame and a version-1 suggestion."""
    import dataclasses

    from aes_planner.messages import encode
    from aes_planner.messages.samples import sample_messages
    from aes_planner.transport import InProcessBus
    from aes_planner.transport.record import Recorder

    path = tmp_path_factory.mktemp("wire") / "run.mcap"
    samples = sample_messages()
    samples["ViewSuggestion"].kind = "waypoint"
    sent = []
    bus = InProcessBus()
    with Recorder(path) as rec:
        rec.attach(bus)
        for name, msg in samples.items():
            bus.publish(f"t/{name.lower()}", msg)
            sent.append((f"/t/{name.lower()}", msg, type(msg).SCHEMA_VERSION))
        rec.write_raw("t/png_frame", encode(samples["PosedFrame"], image_format="png"))
        sent.append(("/t/png_frame", samples["PosedFrame"], 1))
        rec.write_raw("t/old_suggestion", version_1_suggestion(samples["ViewSuggestion"]))
        old = dataclasses.replace(samples["ViewSuggestion"], kind="search", covered_fraction=None, explore=None)
        sent.append(("/t/old_suggestion", old, 1))
    bus.close()
    return path, sent


def version_1_suggestion(msg) -> bytes:
    """A ViewSuggestion as version 1 wrote it: none of the fields appended since (version 2's
    kind byte, version 3's two absent optionals: one flag byte each) at the end of the payload."""
    import dataclasses

    from aes_planner.messages import encode

    newer = 3
    data = bytearray(encode(dataclasses.replace(msg, covered_fraction=None, explore=None))[:-newer])
    magic, fmt, n, _version, payload = struct.unpack_from("<4sBBHI", data, 0)
    struct.pack_into("<4sBBHI", data, 0, magic, fmt, n, 1, payload - newer)
    return bytes(data)


def test_every_message_of_a_recording_decodes_from_its_description_alone(recording):
    from aes_planner.messages import MESSAGE_TYPES

    path, sent = recording
    decoded = decode_recording(path)
    assert [t for t, _ in decoded] == [t for t, _, _ in sent]
    with open(path, "rb") as f:
        schemas = {
            s.name: json.loads(s.data)
            for s in make_reader(f).get_summary().schemas.values()
            if s.encoding == "aes-planner"
        }
    types = {d["type"] for _t, d in decoded}
    assert types == set(MESSAGE_TYPES)
    for (topic, d), (_t, msg, version) in zip(decoded, sent):
        assert d["version"] == version, topic
        assert_matches(d, msg, schemas[f"aes_planner.{d['type']}"]["fields"])
    by_topic = dict(decoded)
    assert by_topic["/t/viewsuggestion"]["kind"] == "waypoint"
    assert by_topic["/t/old_suggestion"]["kind"] == "search"  # version 1: the default
    assert by_topic["/t/png_frame"]["image"]["variant"] == "png"
    assert by_topic["/t/gimbalcommand"]["kind"] == "move" and by_topic["/t/plannerrequest"]["kind"] == "suggest"


def test_the_package_reads_a_version_1_suggestion_as_a_search_result(recording):
    from aes_planner.messages import MessageError, ViewSuggestion, decode, encode
    from aes_planner.messages.samples import sample_messages

    msg = sample_messages()["ViewSuggestion"]
    old = decode(version_1_suggestion(msg), ViewSuggestion)
    assert old.kind == "search" and old.candidates[0].score == msg.candidates[0].score
    newer = bytearray(encode(msg))
    newer[6:8] = struct.pack("<H", ViewSuggestion.SCHEMA_VERSION + 1)
    with pytest.raises(MessageError, match="upgrade"):
        decode(bytes(newer))


def test_the_decoder_refuses_what_the_doc_forbids(recording):
    path, _ = recording
    with open(path, "rb") as f:
        reader = make_reader(f)
        schema, _c, message = next((s, c, m) for s, c, m in reader.iter_messages(topics=["/t/gimbalcommand"]))
    desc = json.loads(schema.data)
    with pytest.raises(WireError):
        decode_with(desc, message.data + b"\0")  # a byte more than the header says
    data = bytearray(message.data)
    data[8:12] = struct.pack("<I", struct.unpack_from("<I", data, 8)[0] + 1)
    with pytest.raises(WireError):
        decode_with(desc, bytes(data) + b"\0")  # consistent length, but a byte nothing reads


def test_docs_wire_md_tables_are_the_field_tables():
    """The topic and type tables of docs/wire.md are what ``aes-planner docs wire`` renders from the
    node types and the field tables today (a field added to a table but not to the page fails here;
    fix with ``aes-planner docs wire --update docs/wire.md``)."""
    from pathlib import Path

    from aes_planner.cli.docs import regions, replace_regions
    from aes_planner.messages import MESSAGE_TYPES

    path = Path(__file__).resolve().parents[2] / "docs" / "wire.md"
    doc = path.read_text(encoding="utf-8")
    assert replace_regions(doc, regions("wire")) == doc, "run: aes-planner docs wire --update docs/wire.md"
    for name, cls in MESSAGE_TYPES.items():
        assert f"### {name}\n\nSchema version {cls.SCHEMA_VERSION}." in doc, name


def decode_as_older(description: dict, data: bytes, known_version: int) -> dict:
    """A reader written for ``known_version`` of a type, as docs/wire.md's versioning rules allow
    one in another language: it decodes the fields it knows (``since`` at most its version) of a
    message of any later version and skips the rest of the payload (the header gives its length)."""
    magic, fmt, name_len, version, payload_len = struct.unpack_from("<4sBBHI", data, 0)
    if magic != b"AESM" or fmt != description["format_version"] or len(data) != 12 + name_len + payload_len:
        raise WireError("header")
    known = [f for f in description["fields"] if f.get("since", 1) <= known_version]
    codes = {int(k): v for k, v in description["array_dtypes"].items()}
    c = Cursor(data[12 + name_len :])
    out = read_fields(c, known, codes, min(version, known_version))
    if c.pos > payload_len:
        raise WireError("read past the payload")
    return {"version": version, "skipped": payload_len - c.pos, **out}


@pytest.mark.parametrize("known_version", [1, 2])
def test_a_reader_of_an_older_version_decodes_a_version_3_suggestion(recording, known_version):
    """Schema 3 appended ``covered_fraction`` and ``explore``: a consumer built for version 1 or 2
    reads a version-3 suggestion's fields it knows unchanged and skips the appended ones."""
    from aes_planner.messages import ViewSuggestion, encode
    from aes_planner.messages.samples import sample_messages

    path, _ = recording
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary().schemas.values()
        schemas = {s.name: json.loads(s.data) for s in summary if s.encoding == "aes-planner"}
    description = schemas["aes_planner.ViewSuggestion"]
    msg = sample_messages()["ViewSuggestion"]
    assert ViewSuggestion.SCHEMA_VERSION == 3 and msg.covered_fraction is not None and msg.explore is not None
    data = encode(msg)
    got = decode_as_older(description, data, known_version)
    assert got["version"] == 3 and "covered_fraction" not in got and "explore" not in got
    assert got["skipped"] > 8 + 1  # the two flags, the f64 and the explore candidate's bytes
    known = [f for f in description["fields"] if f.get("since", 1) <= known_version]
    if known_version == 1:  # kind (version 2) is not known either: skipped with the rest
        assert "kind" not in got
    assert_matches(got, msg, known)
    # what it skipped is exactly what version 3 appended: the full decoder reads them there
    full = decode_with(description, data)
    assert full["covered_fraction"] == msg.covered_fraction
    assert_matches(full["explore"], msg.explore, description["fields"][-1]["value"]["fields"])
