"""Hand-held suggestions checked against the photos themselves.

The field predicts a view's score from a reconstruction; at the input photos the teacher can score
the real images instead. On photo sets the field's error at the inputs is large enough to rank the
wrong part of the walk first (on three CC0-textured scenes its suggestions sat within 7 % of the
cameras' spread of an input photo, but near the inputs the teacher liked least). :func:`anchor_on_photos`
corrects each candidate's field score by the field's error at its nearest photo (the teacher's
score of the real photo minus the field's at that photo's pose) and ranks the candidates again.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import torch

__all__ = ["anchor_on_photos"]

log = logging.getLogger(__name__)


def anchor_on_photos(scorer, photos_c2w: np.ndarray, images: list[np.ndarray], suggestions: list) -> list:
    """``suggestions`` (:class:`~aes_planner.search.Suggestion`, world frame) re-ranked by their field
    score plus the field's error at their nearest photo (``photos_c2w [N, 4, 4]``, ``images`` the
    photos, [H, W, 3] uint8); each keeps its own score in ``terms["field"]``. Unchanged when the
    scorer has no teacher or the photos differ in size."""
    teacher = getattr(scorer, "teacher", None)
    if teacher is None or not suggestions or len({im.shape for im in images}) != 1:
        return suggestions
    with torch.no_grad():
        batch = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).float() / 255.0  # [N, 3, H, W]
        real = teacher.score(batch).double().numpy()  # [N]
        field = scorer.score(torch.as_tensor(photos_c2w, dtype=torch.float64)).score.double().numpy()  # [N]
    error = np.nan_to_num(real - field)  # [N] what the field misses at each photo
    centres = photos_c2w[:, :3, 3]  # [N, 3]
    out = []
    for s in suggestions:
        j = int(np.argmin(np.linalg.norm(centres - s.cam2world[:3, 3], axis=1)))
        out.append(dataclasses.replace(s, score=float(s.score + error[j]), terms={**s.terms, "field": s.score}))
    log.info("photos' teacher scores %s; the field's at their poses %s", np.round(real, 3), np.round(field, 3))
    return sorted(out, key=lambda s: -s.score)
