"""Hand-held suggestions re-ranked by the field's error at their nearest photo."""

from __future__ import annotations

import numpy as np

from aes_planner.photos.anchor import anchor_on_photos
from aes_planner.search.pipeline import Suggestion


class _Teacher:
    def score(self, images):  # [N, 3, H, W] -> [N]: the photo's brightness
        return images.mean(dim=(1, 2, 3))


class _Field:
    """Scores a pose by its x (what a field over-rating one end of the walk does)."""

    teacher = _Teacher()

    def score(self, cam2world):
        class Out:
            score = 0.1 * cam2world[:, 0, 3]

        return Out()


def _pose(x: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 3] = x
    return m


def _suggestion(x: float, score: float) -> Suggestion:
    return Suggestion(_pose(x), np.array([x, 0.0, 0.0]), 0.0, 0.0, score, 1.0, {"score": score})


def test_candidates_near_the_photo_the_teacher_prefers_move_up():
    photos = np.stack([_pose(0.0), _pose(5.0)])
    images = [np.full((8, 8, 3), 230, np.uint8), np.full((8, 8, 3), 20, np.uint8)]  # photo 0 is the better one
    ranked = anchor_on_photos(_Field(), photos, images, [_suggestion(4.9, 0.49), _suggestion(0.2, 0.02)])
    assert [round(float(s.position_m[0]), 1) for s in ranked] == [0.2, 4.9]
    # photo 0: teacher 230/255, field 0 -> +0.902; photo 1: teacher 20/255, field 0.5 -> -0.422
    np.testing.assert_allclose([s.score for s in ranked], [0.02 + 230 / 255, 0.49 + 20 / 255 - 0.5], atol=1e-6)
    assert ranked[0].terms["field"] == 0.02  # the field's own score kept


def test_without_a_teacher_or_with_photos_of_two_sizes_nothing_changes():
    class NoTeacher:
        teacher = None

    photos = np.stack([_pose(0.0), _pose(5.0)])
    given = [_suggestion(4.9, 0.49), _suggestion(0.2, 0.02)]
    assert anchor_on_photos(NoTeacher(), photos, [np.zeros((8, 8, 3), np.uint8)] * 2, given) is given
    sizes = [np.zeros((8, 8, 3), np.uint8), np.zeros((6, 8, 3), np.uint8)]
    assert anchor_on_photos(_Field(), photos, sizes, given) is given
