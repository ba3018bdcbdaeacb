"""Field checks shared by the message types; each raises :class:`MessageError` naming the field."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

import numpy as np

from aes_planner.geometry.rigid import check_rigid
from aes_planner.messages.codec import MessageError

__all__ = ["check_finite", "check_optional_finite", "check_sequence", "check_text", "check_name_map"]

MAX_SEQUENCE = (1 << 63) - 1
_NAME = re.compile(r"^[A-Za-z0-9_.:/\-]{1,64}$")


def check_finite(value, name: str) -> float:
    """A finite real number (not bool), returned as float."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise MessageError(f"{name} must be a finite number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise MessageError(f"{name} must be a finite number, got {v}")
    return v


def check_joint(value, name: str) -> float:
    """A finite joint angle within :data:`aes_planner.geometry.plausible.MAX_JOINT_RAD`."""
    from aes_planner.geometry.plausible import joint_problem

    v = check_finite(value, name)
    problem = joint_problem(name, v)
    if problem is not None:
        raise MessageError(problem)
    return v


def check_optional_finite(value, name: str) -> float | None:
    return None if value is None else check_finite(value, name)


def check_sequence(value, name: str) -> int:
    """A counter: an integer in [0, 2**63)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise MessageError(f"{name} must be an integer >= 0, got {value!r}")
    v = int(value)
    if not 0 <= v <= MAX_SEQUENCE:
        raise MessageError(f"{name} must be in [0, 2**63), got {v}")
    return v


def check_text(value, name: str, max_bytes: int) -> str:
    """Printable text (no control or separator characters but the space: Python's
    ``str.isprintable``; echo prints it to terminals) of at most ``max_bytes`` bytes of UTF-8, the
    cap of the field's :class:`~aes_planner.messages.codec.Str` (:func:`~aes_planner.messages.codec.text_cap`)."""
    if not isinstance(value, str):
        raise MessageError(f"{name} must be a string, got {type(value).__name__}")
    size = len(value.encode("utf-8", "surrogatepass"))
    if size > max_bytes:
        raise MessageError(f"{name} is {size} bytes of UTF-8; the cap is {max_bytes}")
    if value and not value.isprintable():
        raise MessageError(f"{name} contains control characters; use printable text")
    return value


def check_name_map(value, name: str, kind: type, max_entries: int) -> dict:
    """A mapping of short names (``[A-Za-z0-9_.:/-]``, <= 64 chars) to finite floats or ints >= 0."""
    if not isinstance(value, Mapping):
        raise MessageError(f"{name} must be a mapping of names to numbers, got {type(value).__name__}")
    if len(value) > max_entries:
        raise MessageError(f"{name} has {len(value)} entries; the cap is {max_entries}")
    out = {}
    for k, v in value.items():
        if not isinstance(k, str) or not _NAME.match(k):
            raise MessageError(f"{name}: key {k!r} must be 1-64 characters of letters, digits and _ . : / -")
        out[k] = check_sequence(v, f"{name}[{k!r}]") if kind is int else check_finite(v, f"{name}[{k!r}]")
    return out


POSE_TOL = 1e-4  # as aes_planner.geometry.validate_cam2world


def check_pose(value, name: str) -> np.ndarray:
    """A rigid ``[4, 4]`` (or ``[3, 4]``) cam2world, returned as float64 ``[4, 4]``: the checks and
    messages of :func:`aes_planner.geometry.validate_cam2world`, from its numpy-only core."""
    return check_rigid(value, name, POSE_TOL, MessageError)
