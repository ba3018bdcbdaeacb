"""Typed configuration: dataclasses loaded from YAML or dicts, with errors that name the key.

Every node, device and stage has one config dataclass validated in ``__post_init__``. Launch
files, scene files and CLI flags load into the same dataclasses through :func:`from_dict`, which
rejects unknown keys and values of the wrong type with a :class:`ConfigError` naming the full
key path (``rig.joint_limits_deg.pan``) and what to do about it.

YAML is only ever read through :func:`load_yaml`: ``yaml.SafeLoader`` (no object construction)
plus limits (file size, nesting, aliases expanding to at most :data:`YAML_MAX_NODES` values),
duplicate keys refused, and ``1e30`` read as a number as YAML 1.2 does.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
import reprlib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

import yaml

from aes_planner.errors import AesPlannerError

T = TypeVar("T")

__all__ = [
    "ConfigError",
    "from_dict",
    "to_dict",
    "load_yaml",
    "load_yaml_text",
    "read_yaml_text",
    "require",
    "require_finite",
    "require_numbers",
    "short_repr",
    "tag_of",
]

_REPR = reprlib.Repr()
_REPR.maxstring, _REPR.maxother, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict, _REPR.maxlevel = 60, 60, 6, 6, 4, 3


def short_repr(value: Any, limit: int = 200) -> str:
    """``repr(value)`` bounded in size (long strings, lists and nesting elided), for error messages:
    an error must never print, or build, a huge value."""
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class ConfigError(AesPlannerError, ValueError):
    """A configuration value is missing, unknown or out of range.

    ``key`` is the dotted path of the offending entry (``objects[3].material.pattern``).
    """

    def __init__(self, key: str, message: str):
        self.key = key
        self.message = message
        super().__init__(f"{key}: {message}" if key else message)


def _join(prefix: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{prefix}[{key}]"
    return f"{prefix}.{key}" if prefix else str(key)


def distinct(values, key: str) -> list:
    """``values`` without repeats, in order; a repeat is logged (evaluated twice, it would count
    twice in every mean and fake a standard error)."""
    out = list(dict.fromkeys(values))
    if len(out) < len(values):
        repeated = sorted({str(v) for v in values if list(values).count(v) > 1})
        logging.getLogger("aes_planner.config").warning(
            "%s: %s given more than once; each counts once", key, ", ".join(repeated)
        )
    return out


def require(condition: bool, key: str, message: str) -> None:
    """Raise :class:`ConfigError` for ``key`` unless ``condition`` holds."""
    if not condition:
        raise ConfigError(key, message)


def require_finite(value: Any, key: str) -> None:
    """Raise unless every number in ``value`` (a scalar or a flat sequence) is finite."""
    values = value if isinstance(value, (tuple, list)) else (value,)
    for v in values:
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise ConfigError(key, f"expected finite numbers, got {short_repr(value)}")


def require_numbers(obj: Any, names: tuple[str, ...], *, minimum: float = 0.0, strict: bool = True) -> None:
    """Raise for the first attribute of ``obj`` in ``names`` that is not a finite number above
    ``minimum`` (``> minimum``; ``>= minimum`` with ``strict=False``), naming that attribute."""
    op = ">" if strict else ">="
    for name in names:
        v = getattr(obj, name)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        require(
            ok and (v > minimum if strict else v >= minimum),
            name,
            f"must be a finite number {op} {minimum:g}, got {short_repr(v)}",
        )


def require_optional_int(obj: Any, name: str, high: int, unset: str = "the platform's default") -> None:
    """Raise unless the attribute ``name`` of ``obj`` is None or an integer within ``[0, high]``;
    ``unset`` says what None means."""
    v = getattr(obj, name)
    ok = v is None or (isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= high)
    require(ok, name, f"must be an integer in [0, {high}], or unset for {unset}, got {v!r}")


def require_optional_bool(obj: Any, name: str) -> None:
    """Raise unless the attribute ``name`` of ``obj`` is None (the platform's default) or a bool."""
    v = getattr(obj, name)
    require(
        v is None or isinstance(v, bool), name, f"must be true or false, or unset for the platform's default, got {v!r}"
    )


def require_bools(obj: Any, names: tuple[str, ...]) -> None:
    """Raise for the first attribute of ``obj`` in ``names`` that is not a bool, naming it."""
    for name in names:
        v = getattr(obj, name)
        require(isinstance(v, bool), name, f"must be true or false, got {v!r}")


def require_within(obj: Any, names: tuple[str, ...], low: float, high: float) -> None:
    """Raise for the first attribute of ``obj`` in ``names`` (a number, or a flat sequence of them)
    holding anything but finite numbers within ``[low, high]``, naming that attribute."""
    for name in names:
        v = getattr(obj, name)
        values = v if isinstance(v, (tuple, list)) else (v,)
        ok = all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and low <= x <= high
            for x in values
        )
        require(ok, name, f"must be finite numbers within [{low:g}, {high:g}], got {short_repr(v)}")


def tag_of(item: Any, key: str, known: typing.Iterable[str], tag: str = "type") -> str:
    """The type word of a tagged mapping ``{type: WORD, ...}`` (a launch file's node, a scene's
    object or light, a device), checked: ``item`` is a mapping and ``WORD`` a string among
    ``known``; otherwise a :class:`ConfigError` naming ``key.type`` and the words it may be."""
    known = sorted(known)
    if not isinstance(item, Mapping):
        raise ConfigError(
            key, f"expected a mapping with a {tag!r} key (one of {', '.join(known)}), got {short_repr(item)}"
        )
    word = item.get(tag)
    if not isinstance(word, str) or word not in known:
        what = "missing" if tag not in item else f"got {short_repr(word)}"
        raise ConfigError(_join(key, tag), f"must be one of {', '.join(known)}; {what}")
    return word


#: Integers in config files fit in 64 bits (numpy, torch and the wire format hold them there).
INT_MIN, INT_MAX = -(2**63), 2**63 - 1


def _describe(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _convert(tp: Any, value: Any, key: str) -> Any:
    """Convert a YAML value to the annotated type ``tp`` or raise naming ``key``."""
    if tp is Any:
        return value
    origin = get_origin(tp)
    args = get_args(tp)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            # Optional[X]: X's own error names the key and the problem; keep it.
            return _convert(options[0], value, key)
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, key)
            except ConfigError:
                continue
        raise ConfigError(key, f"value {short_repr(value)} matches none of {[_describe(a) for a in args]}")
    if origin is Literal:
        if value not in args:
            raise ConfigError(key, f"must be one of {list(args)}, got {short_repr(value)}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        return from_dict(tp, value, key)
    if origin in (tuple,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(key, f"expected a list, got {type(value).__name__} {short_repr(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, _join(key, i)) for i, v in enumerate(value))
        if args and len(value) != len(args):
            raise ConfigError(key, f"expected {len(args)} values, got {len(value)}: {short_repr(value)}")
        return tuple(_convert(a, v, _join(key, i)) for i, (a, v) in enumerate(zip(args, value)))
    if origin in (list,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(key, f"expected a list, got {type(value).__name__} {short_repr(value)}")
        (arg,) = args or (Any,)
        return [_convert(arg, v, _join(key, i)) for i, v in enumerate(value)]
    if origin in (dict,):
        if not isinstance(value, Mapping):
            raise ConfigError(key, f"expected a mapping, got {type(value).__name__}")
        kt, vt = args or (Any, Any)
        return {_convert(kt, k, key): _convert(vt, v, _join(key, str(k))) for k, v in value.items()}
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f"expected a number, got {short_repr(value)}")
        try:
            value = float(value)
        except OverflowError:  # an integer of hundreds of digits
            raise ConfigError(key, f"expected a finite number, got an integer of {len(str(value))} digits") from None
        if not math.isfinite(value):
            raise ConfigError(key, f"expected a finite number, got {short_repr(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, f"expected an integer, got {short_repr(value)}")
        if not INT_MIN <= value <= INT_MAX:
            raise ConfigError(key, f"expected an integer that fits in 64 bits, got {short_repr(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true or false, got {short_repr(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(key, f"expected a string, got {short_repr(value)}")
        return value
    if tp is Path:
        if not isinstance(value, (str, Path)):
            raise ConfigError(key, f"expected a path, got {short_repr(value)}")
        return Path(value)
    return value


def from_dict(cls: type[T], data: Any, key: str = "") -> T:
    """Build the dataclass ``cls`` from a mapping, recursively, rejecting unknown keys.

    Errors name the dotted key (``prefix`` + field); a key ``cls.RETIRED_KEYS`` (a class attribute
    mapping a key a release replaced to how to rewrite it) is refused with that advice. Validation in the dataclass's
    ``__post_init__`` may raise :class:`ConfigError` with a field name; it is re-raised with
    the full path.
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(key, f"expected a mapping of {cls.__name__} fields, got {short_repr(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
    retired = getattr(cls, "RETIRED_KEYS", {})  # a key a release replaced -> how to rewrite it
    for k in unknown:
        if k in retired:
            raise ConfigError(_join(key, str(k)), retired[k])
    if unknown:
        raise ConfigError(
            _join(key, str(unknown[0])),
            f"unknown key; expected one of: {', '.join(sorted(fields))}",
        )
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], _join(key, name))
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(_join(key, name), f"missing required key for {cls.__name__}")
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        if key and not exc.key.startswith(key):
            raise ConfigError(_join(key, exc.key) if exc.key else key, exc.message) from None
        raise
    except (TypeError, ValueError, ArithmeticError) as exc:
        # A check in __post_init__ that a value it did not expect broke (an overflow, a type):
        # still the input's fault, so name the block it came from rather than print a traceback.
        text = " ".join(str(exc).split())[:200]
        raise ConfigError(key or cls.__name__, f"invalid value ({type(exc).__name__}: {text})") from None


def to_dict(obj: Any) -> Any:
    """The inverse of :func:`from_dict`: plain lists, dicts and scalars, ready for YAML/JSON."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


#: Most values (scalars, lists, mappings) a YAML document may expand to, aliases counted each time
#: they are used: a billion-laughs document of half a kilobyte expands to 10^9 and is refused.
YAML_MAX_NODES = 200_000
#: Deepest nesting of lists and mappings in a YAML document.
YAML_MAX_DEPTH = 64
#: Largest YAML file read (scene files with thousands of objects are well under 1 MiB).
YAML_MAX_BYTES = 8 << 20

# YAML 1.1 (PyYAML) needs a dot in a float: ``1e30`` would be the string "1e30". YAML 1.2 reads it
# as a number, and so does everyone writing a config file.
_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$")


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys and reads ``1e30`` as a float."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    hash(key)
                except TypeError:
                    raise yaml.constructor.ConstructorError(
                        None, None, "a mapping key must be a plain value, not a list or mapping", key_node.start_mark
                    ) from None
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None,
                        None,
                        f"duplicate key {short_repr(key)} (first at line {seen[key].line + 1}); "
                        "each key may appear once per mapping",
                        key_node.start_mark,
                    )
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


_StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789"))


def _expanded_size(node: yaml.Node, path: str) -> int:
    """Values the node graph expands to (aliases counted at every use), without expanding it;
    raises past :data:`YAML_MAX_NODES` or :data:`YAML_MAX_DEPTH`."""
    sizes: dict[int, int] = {}
    # Iterative post-order walk: a deeply nested document must not exhaust Python's stack here.
    stack: list[tuple[yaml.Node, int, bool]] = [(node, 1, False)]
    while stack:
        n, depth, done = stack.pop()
        if id(n) in sizes:
            continue
        if depth > YAML_MAX_DEPTH:
            raise ConfigError("", f"{path}: nested deeper than {YAML_MAX_DEPTH} levels (line {n.start_mark.line + 1})")
        if isinstance(n, yaml.ScalarNode):
            sizes[id(n)] = 1
            continue
        children = [c for pair in n.value for c in pair] if isinstance(n, yaml.MappingNode) else list(n.value)
        if done:
            total = 1 + sum(sizes.get(id(c), 0) for c in children)
            if total > YAML_MAX_NODES:
                raise ConfigError(
                    "",
                    f"{path}: expands to more than {YAML_MAX_NODES} values (anchors and aliases '*' are counted at "
                    "every use); write the values out or split the file",
                )
            sizes[id(n)] = total
            continue
        if any(c is n for c in children):
            raise ConfigError("", f"{path}: a recursive alias (a value that contains itself) is not supported")
        stack.append((n, depth, True))
        stack.extend((c, depth + 1, False) for c in children if id(c) not in sizes)
    return sizes[id(node)]


def load_yaml_text(text: str, path: str = "<string>") -> Any:
    """Parse YAML text safely (see the module docstring); errors are :class:`ConfigError` naming ``path``."""
    if len(text) > YAML_MAX_BYTES:
        raise ConfigError("", f"{path}: {len(text)} characters; YAML files are limited to {YAML_MAX_BYTES} bytes")
    loader = None
    try:
        loader = _StrictLoader(text)
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node, path)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigError("", f"{path}: not valid YAML: {_yaml_problem(exc)}") from None
    except RecursionError:
        raise ConfigError("", f"{path}: nested too deeply to read (more than {YAML_MAX_DEPTH} levels)") from None
    except ConfigError:
        raise
    except (ValueError, OverflowError) as exc:  # a scalar that does not construct: 5000 digits, month 13
        text = " ".join(str(exc).split())[:200]
        raise ConfigError("", f"{path}: not valid YAML: a value cannot be read ({text})") from None
    finally:
        if loader is not None:
            loader.dispose()


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """One bounded line from a PyYAML error: what and where."""
    problem = getattr(exc, "problem", None) or getattr(exc, "reason", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None)
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    if isinstance(exc, yaml.reader.ReaderError):
        where = f" (character {exc.position})"
    text = " ".join(str(problem).split())
    return (text if len(text) <= 300 else text[:297] + "...") + where


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file safely (see the module docstring); errors name the file and line."""
    return load_yaml_text(read_yaml_text(path), str(path))


def read_yaml_text(path: str | Path) -> str:
    """The text of a YAML file, read within :data:`YAML_MAX_BYTES` as UTF-8 (errors name the file),
    for a caller that must look at it before parsing it with :func:`load_yaml_text`."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            raw = f.read(YAML_MAX_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError("", f"{path}: file not found") from None
    except IsADirectoryError:
        raise ConfigError("", f"{path}: is a folder; give a YAML file") from None
    except OSError as exc:
        raise ConfigError("", f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > YAML_MAX_BYTES:
        raise ConfigError("", f"{path}: larger than {YAML_MAX_BYTES} bytes; this is not a config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError("", f"{path}: not UTF-8 text (byte {exc.start}); is it a YAML file?") from None
    return text
