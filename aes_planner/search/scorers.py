"""Build the scorer a search uses from posed frames: the field (default), RGB scoring, or ground truth."""

from __future__ import annotations

from aes_planner.errors import AesPlannerError
from aes_planner.field import SCORER_KINDS
from aes_planner.field.scorer import Scorer
from aes_planner.search.config import SearchConfig
from aes_planner.search.pipeline import SearchError

__all__ = ["SCORERS", "build_search_scorer"]

#: Scorer kinds a search can build from frames (ground truth needs a scene source instead): the
#: field's table (:data:`aes_planner.field.SCORER_KINDS`), read everywhere a kind is offered.
SCORERS = SCORER_KINDS


def build_search_scorer(kind: str, frames: list, cfg: SearchConfig, teacher=None) -> Scorer:
    """``aes_planner.field.build_scorer(kind, frames, ...)`` with the config's render width and budget."""
    if kind not in SCORERS:
        raise SearchError(f"scorer must be one of {list(SCORERS)}, got {kind!r}")
    from aes_planner.field import build_scorer

    knobs = {"render_width_px": cfg.render_width_px}
    if cfg.max_gaussians is not None:
        knobs["max_gaussians"] = cfg.max_gaussians
    try:
        return build_scorer(kind, frames, teacher=teacher, **knobs)
    except ImportError as exc:  # the field's model is not part of this build yet
        raise SearchError(f"the {kind!r} scorer is not available in this build ({exc}); use --scorer rgb") from None
    except SearchError:
        raise
    except AesPlannerError as exc:  # e.g. no field checkpoint, frames the reconstruction refuses
        raise SearchError(f"cannot build the {kind!r} scorer: {exc}") from None
