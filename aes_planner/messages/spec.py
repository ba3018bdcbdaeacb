"""docs/wire.md's layout of every message type, rendered from the field tables.

The tables of docs/wire.md ("The types") are not written by hand: :func:`wire_types_markdown`
renders each registered type from :func:`~aes_planner.messages.codec.describe` (the same JSON a
recording carries), the field notes each :class:`~aes_planner.messages.codec.Field` declares
(``doc=``) and the type's ``WIRE_RULES`` (what a reader refuses beyond the table). ``aes-planner
docs wire --update docs/wire.md`` rewrites the generated part, and a test fails when the page and
the tables disagree, so the page cannot drift from the code. A field added to a table (a new
schema version) appears on the page with its version and default.
"""

from __future__ import annotations

import json

from aes_planner.messages.codec import MESSAGE_TYPES, Field, Message, Struct, describe

__all__ = ["TYPE_ORDER", "field_type", "wire_types_markdown"]

#: The order of the types on the page (a type registered later follows them, by name).
TYPE_ORDER = (
    "PosedFrame",
    "ViewSuggestion",
    "GimbalCommand",
    "GimbalState",
    "Diagnostics",
    "DroneState",
    "PlannerRequest",
    "Clock",
    "ClockAck",
)


def _count(n: int) -> str:
    return f"{n:,}"


def field_type(kind: dict) -> str:
    """The type column of a field from its JSON description (``describe()``'s entry)."""
    t = kind["type"]
    if t in ("str", "bytes"):
        return f"{t} (at most {_count(kind['max_bytes'])} bytes)"
    if t == "array":
        exact = kind.get("exact", [False] * kind["ndim"])
        dims = ", ".join(str(n) if e else f"<= {n}" for n, e in zip(kind["max_shape"], exact))
        return f"array {kind['dtype']} `[{dims}]`"
    if t == "optional":
        return f"optional {field_type(kind['value'])}"
    if t == "list":
        return f"list, `{kind['count']}` count, at most {kind['max']}, of {field_type(kind['items'])}"
    if t == "fixed":
        return f"fixed {kind['n']} x {field_type(kind['items'])}"
    if t == "map":
        return f"map, at most {kind['max']} entries, of str (at most {kind['key']['max_bytes']} bytes) -> {field_type(kind['value'])}"
    if t == "struct":
        return f"`{kind['name']}` (struct, below)"
    return t


def _notes(entry: dict, field: Field) -> str:
    kind = entry
    parts = []
    if kind["type"] == "optional":
        kind = kind["value"]
    if kind["type"] == "enum":
        parts.append(", ".join(f"`{i}` = `{v}`" for i, v in enumerate(kind["values"])))
    if kind["type"] == "union":
        for tag, variant in kind["variants"].items():
            inner = ", ".join(f"`{f['name']}` {field_type(f)}" for f in variant["fields"])
            parts.append(f"tag `{tag}` **{variant['name']}**: {inner}")
    if field.doc:
        parts.append(field.doc)
    if "since" in entry:
        parts.append(f"**since version {entry['since']}**; older messages mean `{json.dumps(entry['default'])}`")
    return "; ".join(parts).replace("|", "\\|")


def _table(fields: tuple[Field, ...]) -> list[str]:
    lines = ["| # | field | type | notes |", "|---|---|---|---|"]
    for i, f in enumerate(fields, 1):
        entry = f.describe()
        kind = entry if entry["type"] != "optional" else entry
        lines.append(f"| {i} | `{f.name}` | {field_type(kind)} | {_notes(entry, f)} |")
    return lines


def _structs(fields: tuple[Field, ...]) -> list[type]:
    """The struct classes a table holds (a list of ``Candidate``...), each once, in order."""
    out: list[type] = []
    for f in fields:
        inner = getattr(f, "item", None) or getattr(f, "inner", None) or f
        if isinstance(inner, Struct) and inner.cls not in out:
            out.append(inner.cls)
    return out


def _section(cls: type[Message]) -> list[str]:
    desc = describe(cls)
    lines = [
        f"### {cls.TYPE_NAME}",
        "",
        f"Schema version {desc['schema_version']}. A whole message, header and type name included, is at most "
        f"{_count(desc['max_bytes'])} bytes.",
    ]
    summary = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split()).replace("``", "`")
    if summary:
        lines += ["", summary]
    lines += ["", *_table(cls.FIELDS)]
    for struct_cls in _structs(cls.FIELDS):
        lines += ["", f"`{struct_cls.__name__}` (struct): its fields, in this order:", "", *_table(struct_cls.FIELDS)]
    rules = tuple(getattr(cls, "WIRE_RULES", ()))
    for struct_cls in _structs(cls.FIELDS):
        rules += tuple(getattr(struct_cls, "WIRE_RULES", ()))
    if rules:
        lines += ["", "Beyond the table, a reader refuses a message with:", ""]
        lines += [f"- {rule}" for rule in rules]
    return lines


def wire_types_markdown() -> str:
    """The "The types" part of docs/wire.md: one section per registered message type."""
    names = [n for n in TYPE_ORDER if n in MESSAGE_TYPES]
    names += sorted(set(MESSAGE_TYPES) - set(names))
    out: list[str] = []
    for name in names:
        out += [*_section(MESSAGE_TYPES[name]), ""]
    return "\n".join(out).rstrip("\n") + "\n"
