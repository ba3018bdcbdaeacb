"""Paths named inside data files stay inside their folder.

A dataset's ``cameras.json``, a nerfstudio ``transforms.json``, a RealEstate10K frame folder and a
scene file name other files by path. Read as they are, an absolute path, ``..`` or a symlink would
let a downloaded file make the package read (and an importer copy into a new dataset) any file
the user can read. :func:`resolve_inside` resolves such a path (symlinks included) and refuses it
unless it lands inside the folder; ``allow_outside=True`` (``--allow-outside-paths`` on the
command line) is the explicit opt-in for files one trusts.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from aes_planner.errors import AesPlannerError

__all__ = ["OutputPathError", "PathOutsideError", "output_file", "output_folder", "output_in", "resolve_inside"]


class PathOutsideError(AesPlannerError, ValueError):
    """A path in a data file that leads out of the file's folder (absolute, ``..`` or a symlink)."""


class OutputPathError(AesPlannerError, ValueError):
    """An output destination (``--out``, ``--json``, ``--cache``...) that cannot be written."""


def output_folder(path: str | Path, flag: str = "--out") -> Path:
    """``path`` as a folder the command can write into, created now (with its parents): checked
    before minutes of work rather than after. Raises :class:`OutputPathError` naming ``flag``
    for an existing file, a parent that is a file, or a place without write permission."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise OutputPathError(f"{flag} {folder}: exists and is not a folder; choose a new or existing folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(
            f"{flag} {folder}: cannot create the folder ({exc.strerror or exc}); choose another"
        ) from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{flag} {folder}: no permission to write there; choose another folder")
    return folder


def new_output_folder(path: str | Path, flag: str = "OUT_DIR") -> Path:
    """``path`` as a folder a command creates itself (it must not exist: a bag, a dataset),
    checked before the work: raises :class:`OutputPathError` naming ``flag`` for anything already
    there, a symlink (dangling or not: the write would go wherever it points) included, or a
    parent that cannot be written."""
    folder = Path(path)
    if folder.is_symlink():
        raise OutputPathError(
            f"{flag} {folder}: is a symlink; give a new folder name (a link is never written through)"
        )
    if folder.exists():
        raise OutputPathError(f"{flag} {folder}: exists; this writes a new folder: give a new name or remove it")
    output_folder(folder.parent if str(folder.parent) else ".", f"{flag} {folder}: its parent")
    return folder


def output_in(folder: str | Path, name: str | Path) -> Path:
    """``folder / name``, a file a command names and writes inside its output folder; raises
    :class:`OutputPathError` when it, or a folder between, is a symlink: a link left in the
    output folder would send the write (an overwrite) wherever it points, or when a folder (or
    anything else but a file) is already there."""
    base = Path(folder)
    path = base / name
    part = path
    while part != base and part != part.parent:
        if part.is_symlink():
            raise OutputPathError(
                f"{part}: is a symlink; the output folder must not redirect its writes elsewhere (remove it)"
            )
        part = part.parent
    if path.exists() and not path.is_file():  # a folder there: cv2.imwrite would fail silently
        raise OutputPathError(
            f"{path}: exists and is not a file (a folder?); remove it or choose another output folder"
        )
    return path


def output_file(path: str | Path, flag: str = "--json") -> Path:
    """``path`` as a file the command can write (its folder created now; an existing file is
    replaced). Raises :class:`OutputPathError` naming ``flag`` for a folder, a symlink (dangling or not)
    or an unwritable place."""
    file = Path(path)
    if file.is_symlink():  # dangling or not: the write would go wherever it points
        raise OutputPathError(f"{flag} {file}: is a symlink; give the file itself (a link is never written through)")
    if file.is_dir():
        raise OutputPathError(f"{flag} {file}: is a folder; give a file name, e.g. {file / 'out.json'}")
    if file.exists() and not file.is_file():
        raise OutputPathError(f"{flag} {file}: is not a regular file; give a file name")
    output_folder(file.parent if str(file.parent) else ".", f"{flag} {file}: its folder")
    if file.exists() and not os.access(file, os.W_OK):
        raise OutputPathError(f"{flag} {file}: no permission to replace this file; choose another name")
    return file


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
