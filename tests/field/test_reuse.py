"""Work the field reuses across builds (perf-2): the packaged model loaded once per process and
the teacher maps of images already seen. Reuse must not change a score."""

import numpy as np
import torch

from aes_planner.field import AestheticField, ScorerConfig
from aes_planner.field import model as field_model
from aes_planner.field.model import clear_feature_cache, load_model, shared_model
from aes_planner.messages import PosedFrame
from aes_planner.teachers import get_teacher

CFG = ScorerConfig(render_width_px=32, max_gaussians=3000)


def test_fields_share_the_packaged_model_and_score_as_a_freshly_loaded_one(rig_frames):
    frames, poses = rig_frames
    teacher = get_teacher("composition")
    a = AestheticField.build(frames, CFG, teacher=teacher)
    b = AestheticField.build(frames[:2], CFG, teacher=teacher)
    assert a.model is b.model is shared_model()
    assert not any(p.requires_grad for p in a.model.parameters())
    fresh = load_model()  # a model of its own: trainable, not the shared one
    assert fresh is not a.model and all(p.requires_grad for p in fresh.parameters())
    own = AestheticField.build(frames, CFG, model=fresh, teacher=teacher)
    q = torch.from_numpy(poses)
    with torch.no_grad():
        torch.testing.assert_close(a.score(q).score, own.score(q).score, rtol=0, atol=0)


def test_cached_teacher_maps_equal_the_teachers_and_the_field_scores_the_same(rig_frames):
    frames, poses = rig_frames
    teacher = get_teacher("composition")
    clear_feature_cache()
    cold = AestheticField.build(frames, CFG, teacher=teacher)  # every map computed
    assert len(field_model._feature_cache) == len(frames)
    warm = AestheticField.build(frames, CFG, teacher=teacher)  # every map from the cache
    images = torch.from_numpy(np.stack([f.image for f in frames])).permute(0, 3, 1, 2).float() / 255.0
    with torch.no_grad():
        direct = teacher.features(images)
    torch.testing.assert_close(cold._inputs.fmaps, direct, rtol=0, atol=0)
    torch.testing.assert_close(warm._inputs.fmaps, direct, rtol=0, atol=0)
    q = torch.from_numpy(poses)
    with torch.no_grad():
        torch.testing.assert_close(cold.score(q).score, warm.score(q).score, rtol=0, atol=0)


def test_a_changed_image_is_not_served_from_the_cache(rig_frames):
    frames, _ = rig_frames
    teacher = get_teacher("composition")
    clear_feature_cache()
    AestheticField.build(frames, CFG, teacher=teacher)
    f = frames[0]
    darker = PosedFrame((f.image // 2).astype(np.uint8), f.intrinsics, f.cam2world, f.stamp_s, f.depth_m, f.frame_id)
    fld = AestheticField.build([darker, *frames[1:]], CFG, teacher=teacher)
    image = torch.from_numpy(darker.image).permute(2, 0, 1)[None].float() / 255.0
    with torch.no_grad():
        torch.testing.assert_close(fld._inputs.fmaps[0], teacher.features(image)[0], rtol=0, atol=0)
    assert not torch.equal(fld._inputs.fmaps[0], AestheticField.build(frames, CFG, teacher=teacher)._inputs.fmaps[0])


def test_the_feature_cache_stays_bounded_however_many_images_pass(rig_frames, monkeypatch):
    frames, _ = rig_frames
    teacher = get_teacher("composition")
    monkeypatch.setattr(field_model, "_FEATURE_CACHE_SIZE", 4)
    clear_feature_cache()
    f = frames[0]
    rng = np.random.default_rng(0)
    for i in range(10):  # 10 distinct images through a cache of 4
        image = rng.integers(0, 256, f.image.shape, dtype=np.uint8)
        frame = PosedFrame(image, f.intrinsics, f.cam2world, float(i), f.depth_m, f.frame_id)
        field_model._features(teacher, [frame], torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255.0)
        assert len(field_model._feature_cache) <= 4
    assert len(field_model._feature_cache) == 4
    clear_feature_cache()
