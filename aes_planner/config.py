"""Typed configuration: dataclasses loaded from YAML or dicts, with errors that name the key.

Every node, device and stage has one config dataclass validated in ``__post_init__``. Launch
files, scene files and CLI flags load into the same dataclasses through :func:`from_dict`, which
rejects unknown keys and values of the wrong type with a :class:`ConfigError` naming the full
key path (``rig.joint_limits_deg.pan``) and what to do about it.

YAML is only ever read with ``yaml.safe_load``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

import yaml

from aes_planner.errors import AesPlannerError

T = TypeVar("T")

__all__ = ["ConfigError", "from_dict", "to_dict", "load_yaml", "require", "require_finite", "require_numbers"]


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


def require(condition: bool, key: str, message: str) -> None:
    """Raise :class:`ConfigError` for ``key`` unless ``condition`` holds."""
    if not condition:
        raise ConfigError(key, message)


def require_finite(value: Any, key: str) -> None:
    """Raise unless every number in ``value`` (a scalar or a flat sequence) is finite."""
    values = value if isinstance(value, (tuple, list)) else (value,)
    for v in values:
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise ConfigError(key, f"expected finite numbers, got {value!r}")


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
            f"must be a finite number {op} {minimum:g}, got {v!r}",
        )


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
        raise ConfigError(key, f"value {value!r} matches none of {[_describe(a) for a in args]}")
    if origin is Literal:
        if value not in args:
            raise ConfigError(key, f"must be one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        return from_dict(tp, value, key)
    if origin in (tuple,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(key, f"expected a list, got {type(value).__name__} {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, _join(key, i)) for i, v in enumerate(value))
        if args and len(value) != len(args):
            raise ConfigError(key, f"expected {len(args)} values, got {len(value)}: {value!r}")
        return tuple(_convert(a, v, _join(key, i)) for i, (a, v) in enumerate(zip(args, value)))
    if origin in (list,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(key, f"expected a list, got {type(value).__name__} {value!r}")
        (arg,) = args or (Any,)
        return [_convert(arg, v, _join(key, i)) for i, v in enumerate(value)]
    if origin in (dict,):
        if not isinstance(value, Mapping):
            raise ConfigError(key, f"expected a mapping, got {type(value).__name__}")
        kt, vt = args or (Any, Any)
        return {_convert(kt, k, key): _convert(vt, v, _join(key, str(k))) for k, v in value.items()}
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(key, f"expected a finite number, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, f"expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(key, f"expected a string, got {value!r}")
        return value
    if tp is Path:
        if not isinstance(value, (str, Path)):
            raise ConfigError(key, f"expected a path, got {value!r}")
        return Path(value)
    return value


def from_dict(cls: type[T], data: Any, key: str = "") -> T:
    """Build the dataclass ``cls`` from a mapping, recursively, rejecting unknown keys.

    Errors name the dotted key (``prefix`` + field). Validation in the dataclass's
    ``__post_init__`` may raise :class:`ConfigError` with a field name; it is re-raised with
    the full path.
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(key, f"expected a mapping of {cls.__name__} fields, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
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


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file with ``yaml.safe_load``; errors name the file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError("", f"{path}: file not found") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError("", f"{path}: not valid YAML: {exc}") from None
