"""Aesthetic teachers: the 2D models the aesthetic field distils and the search maximises.

A :class:`Teacher` splits into ``features(images) -> map`` and ``head(map) -> score`` (see
:mod:`aes_planner.teachers.base`). Built in:

* ``composition`` (default, :class:`CompositionTeacher`): a differentiable, weight-free model of
  framing and composition whose score in ``[0, 1]`` is explained by named terms;
* ``ven`` (:class:`VENTeacher`): the paper's View Evaluation Net; needs the user's weights.

Third-party teachers plug in without editing this package, through the entry-point group
``aes_planner.teachers``: in the plugin's ``pyproject.toml``::

    [project.entry-points."aes_planner.teachers"]
    mymodel = "my_package.teacher:MyTeacher"

where ``MyTeacher(**kwargs)`` (a class or factory) returns a :class:`Teacher`. Then
``get_teacher("mymodel", weights=...)`` and ``aes-planner score --teacher mymodel`` find it.
In-process, :func:`register_teacher` does the same. Built-in names cannot be taken over.

The independent evaluator used for measurement lives in :mod:`aes_planner.teachers.evaluator`.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable
from importlib import metadata
from typing import Any

from aes_planner.teachers.base import Teacher, TeacherError, WeightsError
from aes_planner.teachers.composition import CompositionConfig, CompositionTeacher, CompositionWeights
from aes_planner.teachers.ven import VENTeacher

log = logging.getLogger(__name__)

__all__ = [
    "Teacher",
    "TeacherError",
    "WeightsError",
    "CompositionTeacher",
    "CompositionConfig",
    "CompositionWeights",
    "VENTeacher",
    "ENTRY_POINT_GROUP",
    "DEFAULT_TEACHER",
    "get_teacher",
    "register_teacher",
    "available_teachers",
]

ENTRY_POINT_GROUP = "aes_planner.teachers"
DEFAULT_TEACHER = "composition"

TeacherFactory = Callable[..., Teacher]

_BUILTIN: dict[str, TeacherFactory] = {
    "composition": CompositionTeacher,
    "ven": VENTeacher,
}
_REGISTERED: dict[str, TeacherFactory] = {}


def register_teacher(name: str, factory: TeacherFactory) -> None:
    """Make ``factory(**kwargs) -> Teacher`` available as ``get_teacher(name)`` in this process."""
    if not isinstance(name, str) or not name.strip():
        raise TeacherError(f"a teacher name must be a non-empty string, got {name!r}")
    if name in _BUILTIN:
        raise TeacherError(f"{name!r} is a built-in teacher; register yours under another name")
    if not callable(factory):
        raise TeacherError(f"the factory for teacher {name!r} must be callable, got {factory!r}")
    _REGISTERED[name] = factory


def _entry_points() -> dict[str, metadata.EntryPoint]:
    found = {}
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _BUILTIN:
            log.warning("ignoring entry point %r (%s): it would shadow the built-in teacher", ep.name, ep.value)
            continue
        found.setdefault(ep.name, ep)
    return found


def available_teachers() -> list[str]:
    """Names ``get_teacher`` accepts: built-ins, registered, then installed plugins."""
    names = list(_BUILTIN) + [n for n in _REGISTERED if n not in _BUILTIN]
    names += sorted(n for n in _entry_points() if n not in names)
    return names


def get_teacher(name: str = DEFAULT_TEACHER, **kwargs: Any) -> Teacher:
    """Build the teacher called ``name`` with ``kwargs`` (e.g. ``weights=PATH`` for ``ven``)."""
    factory = _BUILTIN.get(name) or _REGISTERED.get(name)
    source = "built-in" if name in _BUILTIN else "registered"
    if factory is None:
        ep = _entry_points().get(name)
        if ep is None:
            raise TeacherError(
                f"unknown teacher {name!r}; available: {', '.join(available_teachers())}. Plugins register "
                f"through the entry-point group {ENTRY_POINT_GROUP!r} (see `aes-planner teachers list`)."
            )
        try:
            factory = ep.load()
        except Exception as exc:  # a broken plugin must not look like our bug
            raise TeacherError(f"teacher plugin {name!r} ({ep.value}) failed to import: {exc!r}") from exc
        source = f"plugin {ep.value}"
    try:
        inspect.signature(factory).bind(**kwargs)
    except TypeError as exc:
        raise TeacherError(f"teacher {name!r} does not take the options {sorted(kwargs)} ({exc})") from None
    except ValueError:  # no signature to inspect (some builtins): let the call decide
        pass
    teacher = factory(**kwargs)
    if not isinstance(teacher, Teacher):
        raise TeacherError(
            f"teacher {name!r} ({source}) returned {type(teacher).__name__}, not an aes_planner.teachers.Teacher"
        )
    return teacher
