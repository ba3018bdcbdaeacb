"""The composition head's compiled kernel (``explain_scores``) against the torch head it replaces
in the search: the same terms, the score's gradient autograd computes, and no NaN or Inf for any
finite map."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.teachers import CompositionTeacher, TeacherError
from aes_planner.teachers import composition as composition_module
from aes_planner.teachers.synthetic import canvas, draw_disc, draw_horizon

pytest.importorskip("numba")  # the kernel's own tests; without numba explain_scores is the torch head (tested below)

_T32 = CompositionTeacher()
_T64 = CompositionTeacher().double()


def _scene_maps(dtype: torch.dtype) -> torch.Tensor:  # [6, 4, 16, 16]: real maps, then ones the field may render
    images = torch.stack(
        [
            draw_disc(canvas(96, 128, (0.5, 0.5, 0.52)), 0.33, 0.4, 0.12, (0.85, 0.2, 0.15)),
            draw_horizon(canvas(96, 128, (0.3, 0.5, 0.8)), 0.66, 2.0, (0.3, 0.6, 0.2)),
            torch.rand(3, 96, 128, generator=torch.Generator().manual_seed(3)),
        ]
    )
    real = _T32.features(images).to(dtype)
    g = torch.Generator().manual_seed(5)
    blurred = real[:1] * 3.0 + 0.02 * torch.randn(1, 4, 16, 16, generator=g, dtype=dtype)  # signed, off the kinks
    return torch.cat(
        [real, blurred, torch.zeros_like(real[:1]), 1e4 * torch.randn(1, 4, 16, 16, generator=g, dtype=dtype)]
    )


def _both(teacher, fmap):
    """(terms, d score / d fmap) of the torch head and of the kernel."""
    out = []
    for fn in (teacher.explain_map, teacher.explain_scores):
        x = fmap.clone().requires_grad_(True)
        terms = fn(x)
        (grad,) = torch.autograd.grad(terms["score"].sum(), x)
        out.append(({k: v.detach() for k, v in terms.items()}, grad))
    return out


def test_float64_terms_and_gradient_equal_autograds():
    (ref, gref), (got, g) = _both(_T64, _scene_maps(torch.float64))
    assert set(got) == set(ref)
    for k in ref:
        assert got[k].dtype == torch.float64
        torch.testing.assert_close(got[k], ref[k], rtol=0, atol=1e-12, msg=k)
    torch.testing.assert_close(g, gref, rtol=1e-9, atol=1e-12)
    assert float(gref.abs().max()) > 0.1  # a gradient that can fail, not zeros against zeros


def _rel_err(grad: torch.Tensor, exact: torch.Tensor) -> float:
    """Largest error of ``grad`` against ``exact`` (float64), per map relative to its largest entry."""
    scale = exact.abs().flatten(1).amax(1).clamp_min(1e-30)[:, None, None, None]
    return float(((grad.double() - exact) / scale).abs().max())


def test_float32_matches_the_torch_head_and_its_gradient_is_closer_to_the_exact_one():
    fmap = _scene_maps(torch.float32)
    (ref, gref), (got, g) = _both(_T32, fmap)
    (exact, gexact), _ = _both(_T64, fmap.double())  # autograd in float64 of the same float32 map
    for k in ref:
        assert got[k].dtype == torch.float32
        torch.testing.assert_close(got[k], ref[k], rtol=0, atol=5e-6, msg=k)
        torch.testing.assert_close(got[k].double(), exact[k], rtol=0, atol=2e-7, msg=k)  # one float32 rounding
    # The torch head's float32 gradient carries its own rounding (up to ~0.5 of the largest entry on
    # the horizon map: cancellation in the corner energy); the kernel's intermediates are float64.
    assert _rel_err(g, gexact) < 1e-6
    assert _rel_err(g, gexact) <= _rel_err(gref, gexact)


def test_gradcheck_in_float64():
    fmap = _scene_maps(torch.float64)[[0, 3]]  # a subject, and a signed map off the kinks
    fmap = fmap + 0.01 * torch.rand(fmap.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda m: _T64.explain_scores(m)["score"], (fmap.requires_grad_(True),), eps=1e-7, atol=1e-7, rtol=1e-5
    )


def test_only_the_score_carries_a_gradient():
    fmap = _scene_maps(torch.float32)[:2].requires_grad_(True)
    terms = _T32.explain_scores(fmap)
    assert terms["score"].requires_grad
    assert not any(v.requires_grad for k, v in terms.items() if k != "score")
    with torch.no_grad():
        again = _T32.explain_scores(fmap)
    torch.testing.assert_close(again["score"], terms["score"].detach(), rtol=0, atol=0)


def test_checks_the_map_like_the_torch_head():
    with pytest.raises(TeacherError, match="feature map"):
        _T32.explain_scores(torch.zeros(2, 3, 16, 16))


def test_without_numba_it_is_the_torch_head(monkeypatch):
    monkeypatch.setattr(composition_module, "_compiled_head", lambda: None)
    fmap = _scene_maps(torch.float32)[:3]
    got, ref = _T32.explain_scores(fmap), _T32.explain_map(fmap)
    for k in ref:
        torch.testing.assert_close(got[k], ref[k], rtol=0, atol=0)


_SPECIAL = st.sampled_from([0.0, -0.0, 1e-30, -1e-30, 1e-12, 1e3, -1e3, 1e30, -1e30, 3.4e38, -3.4e38])


@settings(max_examples=30)  # ~0.1-0.3 s an example (torch's float64 autograd dominates)
@given(
    scale=st.sampled_from([0.0, 1e-30, 1e-12, 1e-3, 1.0, 1e3, 1e12, 1e30]),
    signed=st.booleans(),
    specials=st.lists(st.tuples(st.integers(0, 2 * 4 * 16 * 16 - 1), _SPECIAL), max_size=40),
    seed=st.integers(0, 2**16),
)
def test_finite_and_exact_for_any_finite_map(scale, signed, specials, seed):
    g = torch.Generator().manual_seed(seed)
    fmap = scale * torch.randn(2, 4, 16, 16, generator=g)
    fmap = fmap if signed else fmap.abs()
    flat = fmap.view(-1)
    for i, v in specials:
        flat[i] = v
    x = fmap.clone().requires_grad_(True)
    got = _T32.explain_scores(x)
    (grad,) = torch.autograd.grad(got["score"].sum(), x)
    assert all(torch.isfinite(v).all() for v in got.values())
    assert torch.isfinite(grad).all()
    # Against autograd in float64 on the same map: the torch head's float32 terms drift on maps like
    # these (subject_size by 6e-4 with one cell at the clamp and the rest at 1e-3), the kernel's do not.
    (exact, gexact), _ = _both(_T64, fmap.double())
    for k in exact:
        torch.testing.assert_close(got[k].double(), exact[k], rtol=0, atol=1e-6, msg=k)
    # Loosely: where the map saturates at the clamp (+-1e3) the corner energy is a difference of
    # ~2e3-sized sums that cancel to ~5e-8, so two float64 evaluations in different orders agree
    # to ~1e-3 of the largest entry there (both are "exact"); on real maps they agree to 1e-9 (above).
    assert _rel_err(grad, gexact) < 1e-2


def test_terms_stay_in_their_ranges():
    got = _T32.explain_scores(_scene_maps(torch.float32))
    for k, v in got.items():
        assert bool(((v >= 0) & (v <= 1)).all()), k
    assert np.isclose(float(got["score"][4]), 0.0, atol=1e-6)  # the all-zero map: nothing to look at


def test_a_second_process_loads_the_kernel_from_numbas_cache():
    _T32.warm()  # this process compiles (or loads) it and writes the cache
    snippet = (
        "import json; from aes_planner.teachers import CompositionTeacher, composition_kernel as k; "
        "CompositionTeacher().warm(); s = k.head.stats; "
        "print(json.dumps([s.cache_hits.total(), s.cache_misses.total()]))"
    )
    out = subprocess.run([sys.executable, "-c", snippet], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    hits, misses = json.loads(out.stdout.strip().splitlines()[-1])
    assert hits >= 1 and misses == 0  # a cold `suggest` loads it; it never compiles
