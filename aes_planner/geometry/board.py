"""A calibration board's geometry: its ``--board`` spec, its corners in the board frame, the
pattern it prints (and the simulator's ``board:`` texture). Detection in images, the printable
files and the calibration itself are :mod:`aes_planner.calibrate`'s; this module is low so that
the simulator can draw a board without importing the calibration.

Spec strings (``--board``):

* ``chessboard:COLSxROWS:SQUARE_M`` -- COLS x ROWS **inner** corners (OpenCV's ``patternSize``;
  the board has COLS+1 x ROWS+1 squares), squares of SQUARE_M metres: ``chessboard:9x6:0.025``.
* ``charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT`` -- COLS x ROWS **squares** with ArUco markers of
  MARKER_M metres from opencv-contrib's dictionary DICT (``DICT_5X5_100``, or ``5X5_100``).

Board frame (object points): origin at the first inner corner, x along a row of corners (to the
right on the printed page), y down the page, z into the board; metres. The printed pattern has
its top-left square black (OpenCV's generator) and one white square of margin on every side.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import cv2
import numpy as np

from aes_planner.errors import AesPlannerError

__all__ = [
    "BOARD_TEXTURE_PREFIX",
    "TEXTURE_PX_PER_SQUARE",
    "BoardError",
    "BoardSpec",
    "board_texture",
    "parse_board",
    "pattern",
]


class BoardError(AesPlannerError, ValueError):
    """A board spec that names no board, or a board that cannot serve the calibration asked."""


_CHESS = re.compile(r"^chessboard:(\d+)x(\d+):([0-9.eE+-]+)$")
_CHARUCO = re.compile(r"^charuco:(\d+)x(\d+):([0-9.eE+-]+):([0-9.eE+-]+):(?:DICT_)?([0-9A-Za-z_]+)$")
_HELP = "write chessboard:COLSxROWS:SQUARE_M (inner corners, e.g. chessboard:9x6:0.025) or charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT (squares, e.g. charuco:7x5:0.04:0.03:DICT_5X5_100)"


@dataclass(frozen=True)
class BoardSpec:
    """A parsed ``--board``: ``kind``, ``cols`` x ``rows`` (inner corners of a chessboard, squares
    of a ChArUco board), ``square_m``, and for ChArUco ``marker_m`` and ``dictionary``."""

    kind: str
    cols: int
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = ""

    @property
    def squares(self) -> tuple[int, int]:
        """Squares across and down (without the white margin)."""
        return (self.cols + 1, self.rows + 1) if self.kind == "chessboard" else (self.cols, self.rows)

    @property
    def corners_grid(self) -> tuple[int, int]:
        """Inner corners across and down."""
        sx, sy = self.squares
        return sx - 1, sy - 1

    @property
    def n_corners(self) -> int:
        cx, cy = self.corners_grid
        return cx * cy

    def size_m(self, margin_squares: int = 1) -> tuple[float, float]:
        """Printed width and height in metres, ``margin_squares`` white squares on every side."""
        sx, sy = self.squares
        return (sx + 2 * margin_squares) * self.square_m, (sy + 2 * margin_squares) * self.square_m

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame ``[N, 3]`` (metres, row by row of ``corners_grid[0]``)."""
        cx, cy = self.corners_grid
        j, i = np.mgrid[0:cy, 0:cx]
        return np.stack([i.ravel() * self.square_m, j.ravel() * self.square_m, np.zeros(cx * cy)], -1)

    @property
    def orientation_unique(self) -> bool:
        """Whether one view fixes which corner is which: a chessboard with an even and an odd count
        of inner corners (a 180 deg turn swaps its colours), or any ChArUco board (marker ids)."""
        return self.kind == "charuco" or (self.cols + self.rows) % 2 == 1

    def aruco_board(self):
        """The ``cv2.aruco.CharucoBoard`` of a ChArUco spec."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, f"DICT_{self.dictionary}"))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, d)

    def __str__(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}:{self.square_m:g}"
        return f"charuco:{self.cols}x{self.rows}:{self.square_m:g}:{self.marker_m:g}:DICT_{self.dictionary}"


def parse_board(text: str) -> BoardSpec:
    """A :class:`BoardSpec` from a ``--board`` string; :class:`BoardError` saying the form otherwise."""
    text = str(text).strip()
    if not text.isascii() or not text.isprintable():  # \d also matches full-width and other digits
        raise BoardError(f"--board {text[:80]!r}: use ASCII letters and digits; {_HELP}")
    m = _CHESS.match(text)
    if m:
        cols, rows, square = int(m.group(1)), int(m.group(2)), _length(m.group(3), "SQUARE_M", text)
        if cols < 3 or rows < 3 or cols > 40 or rows > 40:
            raise BoardError(f"--board {text}: a chessboard needs 3..40 inner corners each way (not squares); {_HELP}")
        return BoardSpec("chessboard", cols, rows, square)
    m = _CHARUCO.match(text)
    if m:
        cols, rows = int(m.group(1)), int(m.group(2))
        square, marker = _length(m.group(3), "SQUARE_M", text), _length(m.group(4), "MARKER_M", text)
        name = m.group(5).upper()
        if not hasattr(cv2.aruco, f"DICT_{name}"):
            raise BoardError(f"--board {text}: no ArUco dictionary DICT_{name}; use e.g. DICT_5X5_100 or DICT_4X4_50")
        if not (3 <= cols <= 40 and 3 <= rows <= 40):
            raise BoardError(f"--board {text}: a ChArUco board needs 3..40 squares each way; {_HELP}")
        if marker >= square:
            raise BoardError(f"--board {text}: MARKER_M must be smaller than SQUARE_M (typically 0.75 of it)")
        spec = BoardSpec("charuco", cols, rows, square, marker, name)
        size = spec.aruco_board().getDictionary().bytesList.shape[0]
        if size < (cols * rows) // 2:
            raise BoardError(f"--board {text}: DICT_{name} has {size} markers, the board needs {(cols * rows) // 2}")
        return spec
    raise BoardError(f"--board {text!r} is not a board spec; {_HELP}")


def _length(value: str, name: str, text: str) -> float:
    try:
        v = float(value)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and 1e-4 <= v <= 1.0):
        raise BoardError(f"--board {text}: {name} must be metres in [0.0001, 1], e.g. 0.025 for 25 mm squares")
    return v


# ----------------------------------------------------------------------------- the pattern
def pattern(spec: BoardSpec, px_per_square: int, margin_squares: int = 1) -> np.ndarray:
    """The board as a grayscale image ``[H, W]`` uint8: whole squares of ``px_per_square`` pixels,
    top-left square black, ``margin_squares`` white squares of margin on every side."""
    sx, sy = spec.squares
    m, p = margin_squares, int(px_per_square)
    if spec.kind == "charuco":
        inner = spec.aruco_board().generateImage((sx * p, sy * p), marginSize=0, borderBits=1)
    else:
        j, i = np.mgrid[0:sy, 0:sx]
        cells = np.where((i + j) % 2 == 0, 0, 255).astype(np.uint8)
        inner = np.kron(cells, np.ones((p, p), np.uint8))
    out = np.full(((sy + 2 * m) * p, (sx + 2 * m) * p), 255, np.uint8)
    out[m * p : (m + sy) * p, m * p : (m + sx) * p] = inner
    return out


#: Texels per square of a ``board:`` texture in a sim scene: an edge blurs over a hundredth of a
#: square, far below a camera pixel at any distance the board is detected from.
TEXTURE_PX_PER_SQUARE = 100
BOARD_TEXTURE_PREFIX = "board:"


def board_texture(image: str) -> np.ndarray:
    """A sim material's ``image: "board:SPEC"`` as an RGB float32 texture ``[h, w, 3]`` in [0, 1]:
    the pattern with one white square of margin, to stretch over a quad of
    :meth:`BoardSpec.size_m` (e.g. ``board:chessboard:9x6:0.06`` on a 0.72 x 0.54 m quad)."""
    spec = parse_board(image[len(BOARD_TEXTURE_PREFIX) :])
    gray = pattern(spec, TEXTURE_PX_PER_SQUARE, 1)
    return np.repeat((gray.astype(np.float32) / 255.0)[..., None], 3, axis=-1)
