"""The 3D aesthetic field (the paper's student), RGB scoring, and the ``Scorer`` interface.

* :class:`Scorer` / :class:`ScoreOutput` (:mod:`~aes_planner.field.scorer`): the contract the
  search, the node and the evaluation use.
* :class:`RGBScorer`: render RGB from the reconstruction and score it with the teacher (the
  paper's baseline).
* :class:`AestheticField`: the student (:mod:`~aes_planner.field.model`).
* :func:`build_scorer`: one entry point for both, from posed frames.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from aes_planner.field.common import ScorerConfig
from aes_planner.field.rgb import RGBScorer
from aes_planner.field.scorer import ScoreOutput, Scorer, ScorerError, check_poses

__all__ = [
    "SCORER_KINDS",
    "AestheticField",
    "RGBScorer",
    "ScoreOutput",
    "Scorer",
    "ScorerConfig",
    "ScorerError",
    "build_scorer",
    "check_poses",
]

SCORER_KINDS = ("field", "rgb")


def __getattr__(name: str) -> Any:  # AestheticField pulls in the model: import it when asked for
    if name == "AestheticField":
        from aes_planner.field.model import AestheticField

        return AestheticField
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build_scorer(kind: str, frames: list, teacher=None, **knobs: Any) -> Scorer:
    """A scorer of ``kind`` (``"field"`` or ``"rgb"``) built from posed ``frames``.

    ``knobs`` are :class:`ScorerConfig` fields (``render_width_px``, ``max_gaussians``,
    ``background``, ``reconstruct``); for ``"field"`` also ``model`` (a loaded
    :class:`~aes_planner.field.model.FieldModel`; default: the shipped checkpoint). ``teacher``
    defaults to the model's teacher for the field and to the default teacher for RGB scoring.
    """
    if kind not in SCORER_KINDS:
        raise ScorerError(f"build_scorer: kind must be one of {list(SCORER_KINDS)}, got {kind!r}")
    model = knobs.pop("model", None)
    names = {f.name for f in fields(ScorerConfig)}
    unknown = sorted(set(knobs) - names)
    if unknown:
        raise ScorerError(f"build_scorer: unknown knobs {unknown}; known: {sorted(names)} (and 'model' for 'field')")
    config = ScorerConfig(**knobs)
    from aes_planner.images import downscale_frame
    from aes_planner.messages import PosedFrame

    frames = [downscale_frame(f) if isinstance(f, PosedFrame) else f for f in frames]  # what the field can see
    if kind == "rgb":
        if model is not None:
            raise ScorerError("build_scorer: 'model' is a knob of the 'field' scorer, not of 'rgb'")
        return RGBScorer.build(frames, teacher=teacher, config=config)
    from aes_planner.field.model import AestheticField

    frames = list(frames)
    if not frames:  # a field of nothing scores every view the same: refused as RGB scoring refuses it
        raise ScorerError(
            "build_scorer('field'): no frames; pass at least one PosedFrame (AestheticField.load_default() "
            "gives an empty field to grow with add_frame)"
        )
    return AestheticField.build(frames, config=config, model=model, teacher=teacher)
