"""Calibration boards: the files to print (PNG with its dots per inch, SVG), and
detection of its corners in an image, labelled the same way in every view.

The spec, the board frame and the pattern are :mod:`aes_planner.geometry.board`'s (re-exported
here); this module writes the printable files and detects the corners.

Image points are in OpenCV's pixel convention (pixel centres at integer coordinates), as every
``cv2`` calibration call expects; add 0.5 for the package's convention
(:mod:`aes_planner.geometry`).
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from aes_planner.geometry.board import BoardError, BoardSpec, parse_board, pattern

__all__ = ["BoardError", "BoardSpec", "Detection", "detect", "parse_board", "pattern", "write_board"]


def _png_with_dpi(gray: np.ndarray, px_per_m: float) -> bytes:
    """PNG bytes of ``gray`` with a pHYs chunk (pixels per metre), so that printing at 100 %
    ("actual size", no fit-to-page) gives the board's physical size."""
    ok, data = cv2.imencode(".png", gray)
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise BoardError("could not encode the board as PNG")
    data = data.tobytes()
    ppm = round(px_per_m)
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    end_ihdr = 8 + 8 + 13 + 4  # signature, IHDR length+type, IHDR data, CRC
    return data[:end_ihdr] + chunk + data[end_ihdr:]


def _svg(spec: BoardSpec, margin_squares: int) -> str:
    """The chessboard as SVG in millimetres (vector: exact at any printer resolution)."""
    w_m, h_m = spec.size_m(margin_squares)
    s = spec.square_m * 1000.0
    sx, sy = spec.squares
    rects = [
        f'<rect x="{(i + margin_squares) * s:.4f}" y="{(j + margin_squares) * s:.4f}" width="{s:.4f}" height="{s:.4f}"/>'
        for j in range(sy)
        for i in range(sx)
        if (i + j) % 2 == 0
    ]
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w_m * 1000:.4f}mm" height="{h_m * 1000:.4f}mm" '
        f'viewBox="0 0 {w_m * 1000:.4f} {h_m * 1000:.4f}">\n<rect width="100%" height="100%" fill="white"/>\n'
        f'<g fill="black">\n{chr(10).join(rects)}\n</g>\n</svg>\n'
    )


def write_board(spec: BoardSpec, out: str | Path, px_per_square: int = 100, margin_squares: int = 1) -> dict:
    """Write the board to ``out`` (``.png``, or ``.svg`` for a chessboard) and return what to tell
    the user: pixel size, physical size, dots per inch at 100 % scale."""
    out = Path(out)
    if not 8 <= px_per_square <= 2000:
        raise BoardError(f"--px-per-square must be in [8, 2000], got {px_per_square}")
    w_m, h_m = spec.size_m(margin_squares)
    info = {
        "board": str(spec),
        "file": str(out),
        "width_mm": round(w_m * 1000, 3),
        "height_mm": round(h_m * 1000, 3),
        "square_mm": round(spec.square_m * 1000, 3),
        "margin_squares": margin_squares,
    }
    if out.suffix.lower() == ".svg":
        if spec.kind != "chessboard":
            raise BoardError("SVG output is for chessboards; write a ChArUco board as .png")
        out.write_text(_svg(spec, margin_squares), encoding="utf-8")
        return {**info, "scale": "print at 100 % (actual size, no fit-to-page)"}
    if out.suffix.lower() != ".png":
        raise BoardError(f"--out {out}: write the board as .png or .svg")
    gray = pattern(spec, px_per_square, margin_squares)
    px_per_m = px_per_square / spec.square_m
    out.write_bytes(_png_with_dpi(gray, px_per_m))
    dpi = px_per_m * 0.0254
    return {
        **info,
        "width_px": int(gray.shape[1]),
        "height_px": int(gray.shape[0]),
        "dpi": round(dpi, 2),
        "scale": f"print at 100 % (actual size, no fit-to-page): {dpi:.1f} dpi",
    }


# ---------------------------------------------------------------------------- detection
@dataclass
class Detection:
    """Corners found in one image: ``image_points [N, 2]`` (OpenCV pixels) of the board's
    ``object_points [N, 3]`` (metres), and the smallest square seen, in pixels."""

    image_points: np.ndarray
    object_points: np.ndarray
    square_px: float


_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


#: Shortest image side in which a board is looked for, pixels (a board's squares need a few pixels each).
MIN_IMAGE_SIDE_PX = 16


def detect(gray: np.ndarray, spec: BoardSpec) -> Detection | None:
    """The board's corners in ``gray [H, W]`` uint8, or None when it is not (wholly) there.

    Chessboards: OpenCV's ``findChessboardCorners`` (adaptive threshold, normalised), the
    sector-based ``findChessboardCornersSB`` when that fails, then ``cornerSubPix`` with OpenCV's
    11x11 window (half-size; narrower where squares are under 24 px). A grid with a corner off the
    line of its neighbours (:func:`_consistent`: a stray corner the detector took for the board's)
    counts as not found by that detector. Corners are put in the board's canonical order (see the
    module docstring) so that every view labels them alike. ChArUco: ``CharucoDetector``, by id.
    """
    if gray.ndim != 2 or min(gray.shape) < MIN_IMAGE_SIDE_PX:  # OpenCV's detectors assert on tiny images
        return None
    if spec.kind == "charuco":
        return _detect_charuco(gray, spec)
    cols, rows = spec.corners_grid
    attempts = (
        lambda: cv2.findChessboardCorners(gray, (cols, rows), flags=_CLASSIC_FLAGS),
        # default flags: with NORMALIZE_IMAGE it missed boards whose white margin is darker than the sky behind
        lambda: cv2.findChessboardCornersSB(gray, (cols, rows), flags=0),
        lambda: cv2.findChessboardCornersSB(gray, (cols, rows), flags=cv2.CALIB_CB_EXHAUSTIVE),
    )
    for attempt in attempts:
        found, corners = attempt()
        if not found:
            continue
        grid = corners.reshape(rows, cols, 2).astype(np.float64)
        square_px = _typical_square(grid)
        # OpenCV's 11x11 (half-size 11) search window, narrowed where a square is under 24 px so that it
        # never reaches the next corner (which pulls the corner off: a 0.9 px RMS instead of 0.4 measured)
        half = 11 if square_px >= 24 else int(max(2, math.floor(square_px / 2) - 1))
        refined = cv2.cornerSubPix(gray, corners.astype(np.float32), (half, half), (-1, -1), _SUBPIX_CRITERIA)
        grid = refined.reshape(rows, cols, 2).astype(np.float64)
        if not _consistent(grid):
            continue
        grid = _canonical(gray, grid)
        return Detection(grid.reshape(-1, 2), spec.object_points(), square_px)
    return None


def _typical_square(grid: np.ndarray) -> float:
    """The median distance between neighbouring corners, pixels."""
    across = np.linalg.norm(np.diff(grid, axis=1), axis=-1).ravel()
    down = np.linalg.norm(np.diff(grid, axis=0), axis=-1).ravel()
    return float(np.median(np.concatenate([across, down])))


def _consistent(grid: np.ndarray) -> bool:
    """Whether ``grid [rows, cols, 2]`` is a smooth grid: the second difference of every three
    neighbours along a row or a column under 0.3 of a square (perspective and lens distortion bend
    a grid far less; a stray corner the detector took for the board's does not)."""
    limit = 0.3 * _typical_square(grid)
    along = np.linalg.norm(grid[:, 2:] - 2 * grid[:, 1:-1] + grid[:, :-2], axis=-1)
    down = np.linalg.norm(grid[2:] - 2 * grid[1:-1] + grid[:-2], axis=-1)
    return bool(along.max(initial=0.0) <= limit and down.max(initial=0.0) <= limit)


def _homography(grid: np.ndarray) -> np.ndarray:
    """The least-squares homography ``[3, 3]`` from board units (squares; corner ``(i, j)`` at
    ``(i, j)``) to the image, of ``grid [rows, cols, 2]``."""
    rows, cols = grid.shape[:2]
    j, i = np.mgrid[0:rows, 0:cols]
    src = np.stack([i.ravel(), j.ravel()], -1).astype(np.float64)
    h, _ = cv2.findHomography(src, grid.reshape(-1, 2), 0)
    return h


def _canonical(gray: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``grid [rows, cols, 2]`` turned so that x runs along rows and y down columns with the board
    seen from its front (right-handed in the image), and corner 0 has a black square diagonally
    outside it (the pattern's top-left square). A board with an even and an odd count is then
    labelled uniquely; on a symmetric one the 180 deg turn stays ambiguous. Directions and the
    squares sampled come from the grid's homography, not from single corners."""
    rows, cols = grid.shape[:2]
    a = (grid[:, -1] - grid[:, 0]).mean(0)  # along a row
    b = (grid[-1] - grid[0]).mean(0)  # down a column
    if a[0] * b[1] - a[1] * b[0] < 0:  # mirrored: reverse each row
        grid = grid[:, ::-1]
    h = _homography(grid)
    outside, beside = cv2.perspectiveTransform(np.array([[[-0.5, -0.5]], [[0.5, -0.5]]]), h).reshape(2, 2)
    if _intensity(gray, outside) > _intensity(gray, beside):  # corner 0 is the far end: turn by 180 deg
        grid = grid[::-1, ::-1]
    return np.ascontiguousarray(grid)


def _intensity(gray: np.ndarray, xy: np.ndarray) -> float:
    patch = cv2.getRectSubPix(gray, (3, 3), (float(xy[0]), float(xy[1])))
    return float(patch.mean())


def _detect_charuco(gray: np.ndarray, spec: BoardSpec) -> Detection | None:
    board = spec.aruco_board()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if ids is None or len(ids) < 6:
        return None
    ids = ids.reshape(-1)
    # OpenCV's ChArUco frame starts at the board's outer corner: shift it to the first inner corner,
    # the chessboard's origin here, so both kinds share one board frame
    obj = np.asarray(board.getChessboardCorners(), dtype=np.float64)[ids] - [spec.square_m, spec.square_m, 0.0]
    img = corners.reshape(-1, 2).astype(np.float64)
    d = np.linalg.norm(img[:, None] - img[None], axis=-1)
    od = np.linalg.norm(obj[:, None] - obj[None], axis=-1)
    near = (od > 0) & (od <= spec.square_m * 1.01)
    square_px = float(d[near].min()) if near.any() else 0.0
    return Detection(img, obj, square_px)
