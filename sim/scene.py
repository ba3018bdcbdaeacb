"""``Scene``: a parsed scene with its primitives and textures ready to render; load and save.

A scene comes from a YAML file (:func:`load_scene` with a path) or from a procedural family
(``"indoor:3"``: family ``indoor``, seed 3; see :data:`aes_planner.sim.FAMILIES`).
:func:`scene_to_yaml` writes any scene back as YAML that loads into the same scene.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import yaml

from aes_planner.config import ConfigError, from_dict, load_yaml, short_repr
from aes_planner.errors import AesPlannerError
from aes_planner.geometry.board import BOARD_TEXTURE_PREFIX, BoardError, board_texture
from aes_planner.paths import PathOutsideError, resolve_inside
from aes_planner.sim.shapes import SHAPES, shape_of
from aes_planner.sim.spec import SceneSpec, spec_to_dict
from aes_planner.sim.texture import MaterialTable, load_image

__all__ = ["Scene", "SceneError", "load_scene", "save_scene", "scene_to_yaml"]

_FAMILY_SPEC = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):([-+]?\d+)$")
#: Images bundled with the package (the showcase scene's picture), readable from any scene file.
ASSETS_DIR = Path(__file__).resolve().parent / "assets"


class SceneError(AesPlannerError, ValueError):
    """A scene that cannot be found or built (unknown family, missing file)."""


class Scene:
    """A scene ready to render: its :class:`SceneSpec` plus the renderer's primitives and the
    decoded image textures.

    Treat it as immutable: to change a scene, change a copy of ``spec`` and build a new
    ``Scene``. ``base_dir`` is where relative image paths start (the YAML file's folder; the
    working directory when None). Instance id ``k`` (in renders) is ``objects[k - 1]``.

    With a ``base_dir`` (a scene read from a file), image paths must lead inside it or into the
    package's bundled ``assets/`` (absolute paths, ``..`` and symlinks that leave are refused);
    ``allow_outside=True`` lifts that for a scene file you trust.
    """

    def __init__(self, spec: SceneSpec, base_dir: str | Path | None = None, allow_outside: bool = False):
        if not isinstance(spec, SceneSpec):
            raise SceneError(
                f"Scene needs a SceneSpec, got {type(spec).__name__}; use load_scene() for files and families"
            )
        self.spec = spec
        self.base_dir = Path(base_dir) if base_dir is not None else None
        # The renderer's arrays, one row per object: shape kind (index into SHAPES), placement
        # (local -> world rotation, centre), size (shapes.py's dims) and bounding-sphere radius.
        m = len(spec.objects)
        shapes = [shape_of(obj) for obj in spec.objects]
        self.kind = np.array([SHAPES.index(kind) for kind, _, _ in shapes], dtype=np.int64)
        self.centres = np.array([centre for _, centre, _ in shapes], dtype=np.float64).reshape(m, 3)
        self.dims = np.array([dims for _, _, dims in shapes], dtype=np.float64).reshape(m, 3)
        self.rotations = np.array([obj.rotation() for obj in spec.objects], dtype=np.float64).reshape(m, 3, 3)
        self.bound_radius = np.array([kind.bound_radius(dims) for kind, _, dims in shapes], dtype=np.float64)
        self.materials = MaterialTable([obj.material for obj in spec.objects])
        cache: dict[Path, np.ndarray] = {}
        self.textures: dict[int, np.ndarray] = {}  # object index -> RGB float32 [h, w, 3]
        for i, obj in enumerate(spec.objects):
            key = f"objects[{i}].material.image"
            if obj.material.image is None:
                continue
            if obj.material.image.startswith(BOARD_TEXTURE_PREFIX):  # a calibration board, drawn exactly
                try:
                    self.textures[i] = board_texture(obj.material.image)
                except BoardError as exc:
                    raise ConfigError(key, str(exc)) from None
                continue
            try:
                if self.base_dir is not None:  # a scene file: its image paths stay inside its folder
                    path = resolve_inside(self.base_dir, obj.material.image, key, allow_outside, (ASSETS_DIR,))
                else:
                    path = self.image_path(obj.material.image)
            except PathOutsideError as exc:
                raise ConfigError(key, str(exc).split(": ", 1)[1]) from None
            except (OSError, ValueError) as exc:
                raise ConfigError(key, f"not a usable file path ({exc})") from None
            if path is not None:
                if path not in cache:
                    cache[path] = load_image(path, f"objects[{i}].material.image")
                self.textures[i] = cache[path]

    def image_path(self, image: str | None) -> Path | None:
        """Where a material's ``image`` entry points (absolute when ``base_dir`` is known); None for
        none and for a generated ``board:SPEC`` texture."""
        if image is None or image.startswith(BOARD_TEXTURE_PREFIX):
            return None
        path = Path(image).expanduser()
        if not path.is_absolute() and self.base_dir is not None:
            path = self.base_dir / path
        return path.resolve() if self.base_dir is not None or path.is_absolute() else path

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def objects(self) -> list:
        return self.spec.objects

    @property
    def lights(self) -> list:
        return self.spec.lights

    @property
    def sky(self):
        return self.spec.sky

    @property
    def rig(self):
        """The :class:`~aes_planner.sim.spec.RigSpec`, or None for a drone scene."""
        return self.spec.rig

    @property
    def drone(self):
        """The :class:`~aes_planner.sim.spec.DroneSpec`, or None for a rig scene."""
        return self.spec.drone

    def intrinsics(self):
        """The scene camera's intrinsics (from its rig or drone section)."""
        return (self.rig or self.drone).intrinsics()

    def __repr__(self) -> str:
        kind = "rig" if self.rig is not None else "drone"
        return f"Scene({self.name!r}, {len(self.objects)} objects, {len(self.lights)} lights, {kind})"


def _load_family(name: str, seed: int) -> Scene:
    from aes_planner.sim.families import FAMILIES

    if name not in FAMILIES:
        raise SceneError(
            f"unknown scene family {name!r}; families: {', '.join(FAMILIES)} (write FAMILY:SEED, e.g. indoor:3)"
        )
    if not 0 <= seed < 2**63:
        raise SceneError(
            f"scene seed {seed} is out of range; write FAMILY:SEED with a seed in [0, 2^63), e.g. indoor:3"
        )
    return Scene(FAMILIES[name](seed))


def load_scene(spec: str | Path | SceneSpec, allow_outside: bool = False) -> Scene:
    """A :class:`Scene` from ``"family:seed"`` (e.g. ``"indoor:3"``), a YAML file path, or a
    :class:`SceneSpec`. Errors in a YAML file raise :class:`ConfigError` naming the key.
    ``allow_outside``: see :class:`Scene` (image paths that leave the scene file's folder)."""
    if isinstance(spec, Scene):
        return spec
    if isinstance(spec, SceneSpec):
        return Scene(spec)
    text = str(spec)
    match = _FAMILY_SPEC.match(text) if len(text) < 100 else None
    try:
        family = match is not None and not Path(text).exists()
        path = Path(text).expanduser()
        is_file = not family and "\x00" not in text and path.is_file()
    except OSError:  # a name too long for the file system
        family, is_file = False, False
    if family:
        return _load_family(match.group(1), int(match.group(2)))
    if not is_file:
        from aes_planner.sim.families import FAMILIES

        raise SceneError(
            f"scene {short_repr(text)} is neither a file nor FAMILY:SEED (families: {', '.join(FAMILIES)}); "
            "give a path to a scene YAML file or e.g. indoor:3"
        )
    data = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("", f"{path}: a scene file must hold a mapping (name, sky, lights, objects, rig or drone)")
    try:
        scene_spec = from_dict(SceneSpec, data)
    except ConfigError as exc:
        raise ConfigError(exc.key, f"{exc.message} (in {path})") from None
    return Scene(scene_spec, base_dir=path.parent.resolve(), allow_outside=allow_outside)


def scene_to_yaml(scene: Scene, relative_to: str | Path | None = None) -> str:
    """The scene as YAML text that :func:`load_scene` reads back into the same scene.

    Image paths are written absolute, or relative to the folder ``relative_to`` (where the
    YAML file will live) when given.
    """
    data = spec_to_dict(scene.spec)
    for obj, spec_obj in zip(data["objects"], scene.objects):
        path = scene.image_path(spec_obj.material.image)
        if path is not None:
            obj["material"]["image"] = os.path.relpath(path, relative_to) if relative_to is not None else str(path)
    header = "# aes-planner scene (format: sim/README.md), written by aes_planner.sim.scene_to_yaml\n"
    return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def save_scene(scene: Scene, path: str | Path) -> Path:
    """Write ``scene`` as a YAML file (image paths relative to it) and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(scene_to_yaml(scene, relative_to=path.parent.resolve()), encoding="utf-8")
    return path
