"""The package computes in the dtypes it states (float32 images, maps and weights; float64 poses)
whatever torch's default dtype: a caller who ran ``torch.set_default_dtype(torch.float64)`` gets
the same teachers' scores, reconstructions and suggestions. Before, building any teacher failed
there ("expected scalar type Float but found Double")."""

import numpy as np
import pytest
import torch

from aes_planner.field import build_scorer
from aes_planner.reconstruct import ReconstructConfig, reconstruct
from aes_planner.search import SearchConfig, search_views
from aes_planner.teachers import VENTeacher, get_teacher

CFG = SearchConfig.preset("fast", render_width_px=32, max_gaussians=3000, steps=4)


@pytest.fixture
def default_float64():
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        yield
    finally:
        torch.set_default_dtype(before)


@pytest.fixture(scope="module")
def ven_weights():
    """A VEN state dict (float32, as a user's checkpoint is)."""
    return {k: v.clone() for k, v in VENTeacher.random(seed=0).net.state_dict().items()}


def _everything(rig_source, rig_frames, depth_frames, ven_weights):
    frames, poses = rig_frames
    images = torch.from_numpy(np.stack([f.image for f in frames])).permute(0, 3, 1, 2).float() / 255.0
    out = {
        "teacher_composition": get_teacher("composition").score(images),
        "teacher_ven": VENTeacher(weights=ven_weights).score(images),
    }
    for name, fs in (("sphere", frames), ("depth", depth_frames[0])):
        rec = reconstruct(fs, ReconstructConfig())
        out[f"rec_{name}"] = rec.gaussians.means
    shifted = []
    for dx_m in (-0.15, 0.15):  # sideways from the middle view: parallax for stereo
        pose = poses[1].copy()
        pose[:3, 3] += dx_m * pose[:3, 0]
        shifted.append(rig_source.capture(pose, depth=False))
    out["rec_stereo"] = reconstruct(shifted, ReconstructConfig(mode="stereo")).gaussians.means
    for kind in ("field", "rgb"):
        scorer = build_scorer(kind, frames, render_width_px=CFG.render_width_px, max_gaussians=CFG.max_gaussians)
        result = search_views(scorer, poses, rig_source.platform, CFG)
        out[f"search_{kind}"] = torch.as_tensor(result.best.cam2world)
        out[f"score_{kind}"] = torch.tensor([result.best.score], dtype=torch.float64)
    return out


@pytest.fixture(scope="module")
def reference(rig_source, rig_frames, depth_frames, ven_weights):
    assert torch.get_default_dtype() == torch.float32
    return _everything(rig_source, rig_frames, depth_frames, ven_weights)


def test_same_results_with_a_float64_default(
    default_float64, reference, rig_source, rig_frames, depth_frames, ven_weights
):
    got = _everything(rig_source, rig_frames, depth_frames, ven_weights)
    assert got.keys() == reference.keys()
    for key, ref in reference.items():
        assert got[key].dtype == ref.dtype, key
        assert got[key].shape == ref.shape, key
        # equal up to the parallel backward's summation order (the search's refined poses)
        torch.testing.assert_close(got[key], ref, atol=1e-4, rtol=1e-4, msg=key)
