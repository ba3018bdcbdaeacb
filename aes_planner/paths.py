"""Paths named inside data files stay inside their folder.

A dataset's ``cameras.json``, a nerfstudio ``transforms.json``, a RealEstate10K frame folder and a
scene file name other files by path. Read as they are, an absolute path, ``..`` or a symlink would
let a downloaded file make the package read (and an importer copy into a new dataset) any file
the user can read. :func:`resolve_inside` resolves such a path (symlinks included) and refuses it
unless it lands inside the folder; ``allow_outside=True`` (``--allow-outside-paths`` on the
command line) is the explicit opt-in for files one trusts.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from aes_planner.errors import AesPlannerError

__all__ = ["PathOutsideError", "resolve_inside"]


class PathOutsideError(AesPlannerError, ValueError):
    """A path in a data file that leads out of the file's folder (absolute, ``..`` or a symlink)."""


def resolve_inside(
    root: str | Path,
    entry: str | Path,
    key: str,
    allow_outside: bool = False,
    also_inside: Iterable[Path] = (),
) -> Path:
    """``root / entry`` resolved (symlinks followed); raises :class:`PathOutsideError` naming ``key``
    unless it lies inside ``root`` (or one of ``also_inside``), or ``allow_outside`` is set."""
    text = str(entry)
    if "\x00" in text:
        raise PathOutsideError(f"{key}: the path contains a NUL character")
    base = Path(root).resolve()
    path = (base / Path(text).expanduser() if allow_outside else base / text).resolve()
    if allow_outside:
        return path
    for folder in (base, *(Path(p).resolve() for p in also_inside)):
        if path == folder or folder in path.parents:
            return path
    raise PathOutsideError(
        f"{key}: {text!r} leads outside {base} (absolute paths, '..' and symlinks that leave the folder are "
        "refused); move the file into the folder, or, if you trust this file, pass allow_outside=True "
        "(--allow-outside-paths on the command line)"
    )
