"""Aesthetic teachers: the 2D models the aesthetic field distils and the search maximises.

A :class:`Teacher` splits into ``features(images) -> map`` and ``head(map) -> score`` (see
:mod:`aes_planner.teachers.base`). Built in: ``composition`` (default,
:class:`CompositionTeacher`), a differentiable, weight-free model of framing and composition
whose score in ``[0, 1]`` is explained by named terms.
"""

from aes_planner.teachers.base import Teacher, TeacherError, WeightsError
from aes_planner.teachers.composition import CompositionConfig, CompositionTeacher, CompositionWeights

__all__ = ["Teacher", "TeacherError", "WeightsError", "CompositionTeacher", "CompositionConfig", "CompositionWeights"]
