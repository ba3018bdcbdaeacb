"""Helpers shared by tests, imported explicitly (``from tests.helpers import ...``); fixtures stay in
the conftest.py files.

* rasterizer tests: render with any backend, collect every gradient, compare with a tolerance;
* reconstruction tests: an analytic scene (ground, sphere, wall) whose surfaces are known in
  closed form, and capturing posed frames from the simulator;
* import checks: run code in a fresh interpreter where optional dependencies cannot be imported;
* bad-input sweeps: write a file, list a folder, write a damaged field checkpoint.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from aes_planner.gaussians import Gaussians, rasterize
from aes_planner.gaussians.numba_backend import available as numba_available
from aes_planner.gaussians.reference import rasterize_dense
from aes_planner.geometry import Intrinsics, look_at
from aes_planner.messages import PosedFrame

# ------------------------------------------------------------------------------- rasterizer
FAST_BACKENDS = ["numba", "torch"] if numba_available() else ["torch"]
GRAD_FIELDS = ("means", "quats", "log_scales", "opacities", "colors", "features")
OUTPUTS = ("rgb", "features", "depth", "alpha")


def render(backend: str, g: Gaussians, world2cam, K, width, height, background=None):
    """Outputs as a dict; backend 'dense' is the reference."""
    if backend == "dense":
        return rasterize_dense(g, world2cam, K, width, height, background=background)
    out = rasterize(g, world2cam, K, width, height, background=background, backend=backend)
    return {k: getattr(out, k) for k in OUTPUTS}


def outputs_and_grads(backend, g, world2cam, K, width, height, background=None, seed=1):
    """Render, take a fixed random linear functional of every output, and return
    (outputs, gradients) for the Gaussian fields, world2cam and background."""
    g = g.detach().clone().requires_grad_()
    world2cam = world2cam.detach().clone().requires_grad_()
    if background is not None:
        background = background.detach().clone().requires_grad_()
    out = render(backend, g, world2cam, K, width, height, background)
    gen = torch.Generator().manual_seed(seed)
    loss = sum((out[k] * torch.randn(out[k].shape, generator=gen, dtype=out[k].dtype)).sum() for k in OUTPUTS)
    loss.backward()
    grads = {f: getattr(g, f).grad for f in GRAD_FIELDS}
    grads["world2cam"] = world2cam.grad
    if background is not None:
        grads["background"] = background.grad
    return {k: v.detach() for k, v in out.items()}, grads


def assert_close(actual, expected, rtol, atol_frac, what):
    """|a - e| <= max(atol_frac * max|e|, 1e-12) + rtol * |e| elementwise, with a readable failure."""
    assert actual.shape == expected.shape, f"{what}: shape {tuple(actual.shape)} != {tuple(expected.shape)}"
    if expected.numel() == 0:
        return
    scale = float(expected.abs().max())
    err = (actual.double() - expected.double()).abs()
    bound = max(atol_frac * scale, 1e-12) + rtol * expected.double().abs()
    worst = float((err - bound).max())
    assert worst <= 0, f"{what}: max error {float(err.max()):.3e} exceeds tolerance (scale {scale:.3e})"


# --------------------------------------------------------------------------- reconstruction
SPHERE_CENTRE = np.array([3.0, 0.4, 0.8])
SPHERE_RADIUS = 0.5
WALL_X = 6.0  # the wall's front face

ANALYTIC = {
    "name": "analytic",
    "objects": [
        {
            "type": "plane",
            "name": "ground",
            "point_m": [0, 0, 0],
            "normal": [0, 0, 1],
            "material": {
                "albedo": [0.7, 0.6, 0.5],
                "pattern": {"kind": "checker", "colour2": [0.3, 0.3, 0.35], "scale_m": 0.4},
            },
        },
        {
            "type": "sphere",
            "name": "ball",
            "centre_m": SPHERE_CENTRE.tolist(),
            "radius_m": SPHERE_RADIUS,
            "material": {
                "albedo": [0.2, 0.4, 0.8],
                "pattern": {"kind": "noise", "colour2": [0.9, 0.9, 0.9], "scale_m": 0.1, "octaves": 2, "seed": 3},
            },
        },
        {
            "type": "box",
            "name": "wall",
            "centre_m": [WALL_X + 0.1, 0, 2],
            "size_m": [0.2, 12, 4],
            "material": {
                "albedo": [0.8, 0.75, 0.7],
                "pattern": {
                    "kind": "stripes",
                    "colour2": [0.5, 0.3, 0.3],
                    "scale_m": 0.6,
                    "duty": 0.4,
                    "angle_deg": 30,
                },
            },
        },
    ],
    "rig": {
        "pan_tilt": {"base_xyz_m": [0.0, 0.0, 1.2], "pan_limits_deg": [-60, 60], "tilt_limits_deg": [-40, 30]},
        "camera": {"width": 64, "height": 48, "hfov_deg": 60.0},
    },
}


def surface_distance(points: np.ndarray) -> np.ndarray:
    """Distance (m) from each point ``[N, 3]`` to the nearest analytic surface seen from the front."""
    ground = np.abs(points[:, 2])
    sphere = np.abs(np.linalg.norm(points - SPHERE_CENTRE, axis=1) - SPHERE_RADIUS)
    wall = np.abs(points[:, 0] - WALL_X)
    return np.minimum(np.minimum(ground, sphere), wall)


def capture(
    scene, cam2world: np.ndarray, intrinsics: Intrinsics, with_depth: bool = True, supersample: int = 1
) -> PosedFrame:
    from aes_planner.sim import render

    out = render(scene, cam2world, intrinsics, supersample)
    return PosedFrame(
        out.rgb,
        intrinsics,
        cam2world,
        depth_m=out.depth_m if with_depth else None,
        extras={"instance_id": out.instance_id},
    )


def looking_at_ball(eye) -> np.ndarray:
    return look_at(np.asarray(eye, float), SPHERE_CENTRE)


# ---------------------------------------------------------------------------- import checks
def run_python_without(blocked: tuple[str, ...], code: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter in which importing any module of ``blocked`` fails
    (``sys.modules[name] = None``): what imports without an optional dependency (stdout, stderr as text)."""
    prelude = "import sys; " + "; ".join(f"sys.modules[{name!r}] = None" for name in blocked) + "\n"
    return subprocess.run([sys.executable, "-c", prelude + code], capture_output=True, text=True)


def wait_for(pred, timeout_s: float = 20.0, poll_s: float = 0.01) -> bool:
    """Poll `pred` until it holds or `timeout_s` passes; generous, as CI hosts are shared and loaded.

    Tests wait on a condition rather than for a fixed time, so a slow host makes them slower, not red.
    """
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(poll_s)
    return bool(pred())


# ------------------------------------------------------------------------------ bad-input sweeps
def write_file(folder: Path, name: str, text: str) -> Path:
    (folder / name).write_text(text)
    return folder / name


def tree(folder: Path) -> set:
    """Every path under ``folder``, relative to it: compare before and after to see what was written."""
    return {p.relative_to(folder) for p in folder.rglob("*")}


class Evil:
    """Prints ``unpickled!`` when unpickled: a loader that must never unpickle is checked by its absence."""

    def __reduce__(self):
        return (print, ("unpickled!",))


def corrupt_checkpoint(ckpt, how):
    """A copy of a field model checkpoint damaged as ``how`` says (see the cases in the branches)."""
    c = dict(ckpt)
    sd = dict(c["state_dict"])
    name = next(k for k, v in sd.items() if v.is_floating_point())
    if how == "nan":
        sd[name] = torch.full_like(sd[name], float("nan"))
    elif how == "huge":
        sd[name] = torch.full_like(sd[name], 1e30)
    elif how == "shape":
        sd[name] = sd[name].flatten()[:1]
    elif how == "state_str":
        return {**c, "state_dict": "x"}
    elif how == "no_config":
        del c["model_config"]
        return c
    elif how == "channels":
        return {**c, "feature_channels": -3}
    elif how == "channels_str":
        return {**c, "feature_channels": "abc"}
    elif how == "size":
        return {**c, "feature_size": 5}
    return {**c, "state_dict": sd}


def write_checkpoint(path, ckpt, how=None):
    """Write a checkpoint in the trainer's format (``tensorfile.save``: the trainer's own writer
    refuses NaN, a damaged file may still hold them); ``how="objects"``: then swap a weight for a
    pickled object array (``np.savez`` pickles those on write), which the loader must refuse unread."""
    from aes_planner import tensorfile

    tensorfile.save(path, ckpt)
    if how == "objects":
        with np.load(path) as npz:
            arrays = {k: npz[k] for k in npz.files}
        arrays["a0"] = np.array([Evil()], dtype=object)
        np.savez(path, **arrays)
    return path


def raw_intrinsics(fx, fy, cx, cy, width, height):
    """An :class:`~aes_planner.geometry.camera.Intrinsics` built past its own validation (it
    refuses these itself): what a forged message or a broken file carries."""
    from aes_planner.geometry.camera import Intrinsics

    k = object.__new__(Intrinsics)
    for name, value in zip(("fx", "fy", "cx", "cy", "width", "height"), (fx, fy, cx, cy, width, height)):
        object.__setattr__(k, name, value)
    return k
