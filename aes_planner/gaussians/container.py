"""``Gaussians``: the 3D Gaussian scene the rasterizer draws and reconstruction builds."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from aes_planner import tensorfile
from aes_planner.errors import AesPlannerError

__all__ = ["Gaussians", "GaussianError"]

log = logging.getLogger(__name__)

FORMAT_VERSION = 2  # 2: an aes_planner.tensorfile .npz (1 was torch.save's pickle-based format)
# Float fields follow the container's dtype; provenance fields are always int32.
_FLOAT_FIELDS = ("means", "quats", "log_scales", "opacities", "colors", "features")
_INT_FIELDS = ("source_frame", "source_pixel")
_TRAILING_SHAPES = {
    "means": (3,),
    "quats": (4,),
    "log_scales": (3,),
    "opacities": (),
    "colors": (3,),
    "source_frame": (),
    "source_pixel": (2,),
}


class GaussianError(AesPlannerError, ValueError):
    """Gaussians or rasterizer inputs with the wrong shape, dtype, device or values."""


@dataclass
class Gaussians:
    """N anisotropic 3D Gaussians with colour, C feature channels and provenance.

    Parameterisation (what the rasterizer differentiates):

    * ``means``: ``[N, 3]`` world-frame centres, metres.
    * ``quats``: ``[N, 4]`` rotations, ``(w, x, y, z)``, any norm (normalised when used; a zero
      quaternion is the identity, with zero gradient).
    * ``log_scales``: ``[N, 3]`` natural log of the standard deviations along the rotated axes,
      metres. ``scales = exp(log_scales)``.
    * ``opacities``: ``[N]`` **activated** opacities in ``[0, 1]`` (not logits). An optimiser that
      wants an unconstrained parameter keeps logits and passes ``torch.sigmoid(logits)``;
      :meth:`from_logits` does that.
    * ``colors``: ``[N, 3]`` RGB, linear, nominally in ``[0, 1]`` (not clamped).
    * ``features``: ``[N, C]`` any ``C >= 0`` channels, rendered like colours.
    * ``source_frame``: ``[N]`` int32 index of the frame a Gaussian came from, ``-1`` = unknown.
    * ``source_pixel``: ``[N, 2]`` int32 ``(column, row)`` of the pixel it came from, ``-1`` =
      unknown.

    All float fields share one dtype and every field one device. Construction validates shapes;
    values are checked by :meth:`validate` (the rasterizer calls it).
    """

    means: Tensor  # [N, 3]
    quats: Tensor  # [N, 4]
    log_scales: Tensor  # [N, 3]
    opacities: Tensor  # [N]
    colors: Tensor  # [N, 3]
    features: Tensor | None = None  # [N, C]; None -> C = 0
    source_frame: Tensor | None = None  # [N] int32; None -> all -1
    source_pixel: Tensor | None = None  # [N, 2] int32; None -> all -1

    def __post_init__(self):
        for name in ("means", "quats", "log_scales", "opacities", "colors"):
            if not isinstance(getattr(self, name), Tensor):
                raise GaussianError(
                    f"Gaussians.{name} must be a torch.Tensor, got {type(getattr(self, name)).__name__}"
                )
        n = self.means.shape[0] if self.means.dim() >= 1 else -1
        dtype, device = self.means.dtype, self.means.device
        if dtype not in (torch.float32, torch.float64):  # the rasterizers compute in these two
            raise GaussianError(f"Gaussians.means must be float32 or float64, got {dtype}; use .float()")
        if self.features is None:
            self.features = torch.zeros(n, 0, dtype=dtype, device=device)
        if self.source_frame is None:
            self.source_frame = torch.full((n,), -1, dtype=torch.int32, device=device)
        if self.source_pixel is None:
            self.source_pixel = torch.full((n, 2), -1, dtype=torch.int32, device=device)
        for name in _FLOAT_FIELDS + _INT_FIELDS:
            t = getattr(self, name)
            if not isinstance(t, Tensor):
                raise GaussianError(f"Gaussians.{name} must be a torch.Tensor, got {type(t).__name__}")
            trailing = _TRAILING_SHAPES.get(name, (t.shape[-1],) if t.dim() == 2 else (-1,))
            if tuple(t.shape) != (n, *trailing):
                want = ", ".join(["N", *map(str, trailing)]) if name != "features" else "N, C"
                raise GaussianError(
                    f"Gaussians.{name} must have shape [{want}] with N = {n} (from means), got {tuple(t.shape)}"
                )
            if t.device != device:
                raise GaussianError(f"Gaussians.{name} is on {t.device} but means on {device}; move with .to(device)")
            if name in _FLOAT_FIELDS and t.dtype != dtype:
                raise GaussianError(f"Gaussians.{name} is {t.dtype} but means are {dtype}; use .to(dtype=...)")
            if name in _INT_FIELDS and t.dtype != torch.int32:
                raise GaussianError(f"Gaussians.{name} must be int32, got {t.dtype}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(
        cls, channels: int = 0, dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu"
    ) -> Gaussians:
        """No Gaussians, ``channels`` feature channels."""
        z = lambda *s: torch.zeros(*s, dtype=dtype, device=device)  # noqa: E731
        return cls(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 3), z(0, channels))

    @classmethod
    def from_logits(
        cls,
        means: Tensor,  # [N, 3]
        quats: Tensor,  # [N, 4]
        log_scales: Tensor,  # [N, 3]
        opacity_logits: Tensor,  # [N]
        colors: Tensor,  # [N, 3]
        features: Tensor | None = None,  # [N, C]
    ) -> Gaussians:
        """Gaussians whose opacities are ``sigmoid(opacity_logits)`` (differentiable)."""
        return cls(means, quats, log_scales, torch.sigmoid(opacity_logits), colors, features)

    @staticmethod
    def cat(parts: Sequence[Gaussians]) -> Gaussians:
        """Concatenate along N; all parts must share C, dtype and device."""
        parts = list(parts)
        if not parts:
            raise GaussianError("Gaussians.cat needs at least one Gaussians; use Gaussians.empty(C) for none")
        channels = {p.num_channels for p in parts}
        if len(channels) > 1:
            raise GaussianError(f"Gaussians.cat: parts have different feature channels {sorted(channels)}")
        return Gaussians(**{f: torch.cat([getattr(p, f) for p in parts]) for f in _names()})

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num_channels(self) -> int:
        """C, the number of feature channels."""
        return self.features.shape[1]

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def scales(self) -> Tensor:  # [N, 3]
        return self.log_scales.exp()

    def __getitem__(self, index: int | slice | Tensor | Sequence[int]) -> Gaussians:
        """Select Gaussians by slice, integer indices or a boolean mask ``[N]`` (differentiable)."""
        if isinstance(index, int):
            index = slice(index, index + 1 if index != -1 else None)
        if isinstance(index, Tensor) and index.dtype == torch.bool and tuple(index.shape) != (len(self),):
            raise GaussianError(f"boolean mask must have shape [{len(self)}], got {tuple(index.shape)}")
        if not isinstance(index, (slice, Tensor)):
            index = torch.as_tensor(index, dtype=torch.long, device=self.device)
        return Gaussians(**{f: getattr(self, f)[index] for f in _names()})

    def to(self, device: str | torch.device | None = None, dtype: torch.dtype | None = None) -> Gaussians:
        """Move to ``device`` and/or cast the float fields to ``dtype`` (provenance stays int32)."""
        out = {}
        for f in _names():
            t = getattr(self, f)
            out[f] = t.to(device=device, dtype=dtype if f in _FLOAT_FIELDS else None)
        return Gaussians(**out)

    def detach(self) -> Gaussians:
        return Gaussians(**{f: getattr(self, f).detach() for f in _names()})

    def clone(self) -> Gaussians:
        return Gaussians(**{f: getattr(self, f).clone() for f in _names()})

    def requires_grad_(self, requires_grad: bool = True) -> Gaussians:
        """Make every float field a leaf that requires grad (in place); returns self."""
        for f in _FLOAT_FIELDS:
            getattr(self, f).requires_grad_(requires_grad)
        return self

    def float_tensors(self) -> dict[str, Tensor]:
        """The differentiable fields by name (``means`` ... ``features``)."""
        return {f: getattr(self, f) for f in _FLOAT_FIELDS}

    def validate(self) -> None:
        """Raise :class:`GaussianError` for non-finite values or opacities outside ``[0, 1]``."""
        if not len(self):
            return
        # On the CPU in numpy: np.isfinite(a).all() is ~4x cheaper than a float64 sum and ~100x
        # cheaper than torch's isfinite().all() at 10k-320k values (docs/benchmarks.md, "Figures
        # behind code comments"), and torch ops above its parallel grain size wake its OpenMP pool,
        # whose spinning threads slow down the rasterizer's own threads that run next.
        if self.device.type == "cpu":
            arrays = [getattr(self, f).detach().numpy() for f in _FLOAT_FIELDS]
            finite = [bool(np.isfinite(a).all()) for a in arrays]
            lo, hi = (float(arrays[3].min()), float(arrays[3].max()))
        else:
            with torch.no_grad():
                finite = [bool(torch.isfinite(getattr(self, f)).all()) for f in _FLOAT_FIELDS]
                lo, hi = (float(v) for v in torch.aminmax(self.opacities))
        if not all(finite):
            f = _FLOAT_FIELDS[finite.index(False)]
            raise GaussianError(f"Gaussians.{f} has NaN or Inf entries; check the optimiser or the source data")
        if not (lo >= 0 and hi <= 1):
            raise GaussianError(
                "Gaussians.opacities must be activated values in [0, 1]; pass torch.sigmoid(logits) "
                "or build with Gaussians.from_logits"
            )

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> Path:
        """Write the tensors and a version number as an :mod:`aes_planner.tensorfile` ``.npz``
        (atomically; read back by :meth:`load`, never unpickled). Conventional suffix: ``.npz``."""
        path = Path(path)
        data = {f: getattr(self, f).detach().cpu().contiguous() for f in _names()}
        tensorfile.save(path, {"format_version": FORMAT_VERSION, **data})
        log.debug("saved %d Gaussians to %s", len(self), path)
        return path

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> Gaussians:
        """Read a file written by :meth:`save` (``np.load(allow_pickle=False)``: nothing is unpickled;
        an old ``torch.save`` file is refused)."""
        path = Path(path)
        if not path.exists():
            raise GaussianError(f"{path}: no such Gaussians file")
        try:
            data = tensorfile.load(path)
        except tensorfile.LegacyTorchFileError as exc:
            raise GaussianError(f"{exc}; save the Gaussians again with Gaussians.save") from None
        except tensorfile.TensorFileError as exc:
            raise GaussianError(f"not a Gaussians file written by Gaussians.save: {exc}") from None
        if not isinstance(data, dict) or "format_version" not in data:
            raise GaussianError(f"{path}: not a Gaussians file written by Gaussians.save")
        version = data.pop("format_version")
        if type(version) is not int or version != FORMAT_VERSION:
            raise GaussianError(
                f"{path}: Gaussians format version {str(version)[:20]}, this package reads {FORMAT_VERSION}"
            )
        missing = [f for f in _names() if f not in data]
        if missing:
            raise GaussianError(f"{path}: Gaussians file lacks {missing}")
        bad = [f for f in _names() if not isinstance(data[f], torch.Tensor)]
        if bad:
            raise GaussianError(f"{path}: Gaussians file entries {bad} are not tensors")
        return cls(**{f: data[f].to(device) for f in _names()})

    def __repr__(self) -> str:
        return f"Gaussians(N={len(self)}, C={self.num_channels}, dtype={self.dtype}, device={self.device})"


def _names() -> Iterable[str]:
    return [f.name for f in fields(Gaussians)]
