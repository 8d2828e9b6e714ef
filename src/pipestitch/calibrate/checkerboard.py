"""Checkerboard corners in fisheye images (OpenCV), and the board's own geometry.

Detection uses ``cv2.findChessboardCornersSB`` (the sector-based detector: it is
far more tolerant of strong radial distortion near a fisheye's rim than the
classic quad detector); when it fails the classic ``cv2.findChessboardCorners``
is tried. Corners are then refined by ``cv2.cornerSubPix`` with a window scaled to
the corner spacing (a large one straddles neighbouring, strongly distorted
squares near the rim). A board may be seen rotated by 90°: both orientations of
``cols x rows`` are tried and the object points follow the one found.

What this module does not do: read files or decide which views are good enough
for a calibration (:mod:`pipestitch.calibrate.camera_fit` rejects views by their
residuals).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipestitch.camera.frames import to_grey

__all__ = ["Board", "BoardView", "detect_board", "parse_board"]


@dataclass(frozen=True)
class Board:
    """A planar checkerboard.

    Attributes
    ----------
    cols, rows : int
        Inner corners per row and per column (OpenCV's ``patternSize``).
    square_mm : float
        Side of one square.
    """

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"board: expected at least 2x2 inner corners, got "
                             f"{self.cols}x{self.rows}")
        if not (np.isfinite(self.square_mm) and self.square_mm > 0):
            raise ValueError(f"board: square size must be positive, got {self.square_mm}")

    def object_points(self) -> np.ndarray:
        """(cols·rows, 3) board points in mm, in OpenCV's corner order (row by row), z = 0."""
        j, i = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        return np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square_mm

    def transposed(self) -> Board:
        """The same board seen rotated by 90° (rows and columns swapped)."""
        return Board(self.rows, self.cols, self.square_mm)


@dataclass(frozen=True)
class BoardView:
    """Corners of one board found in one image.

    Attributes
    ----------
    pixels : numpy.ndarray, shape (N, 2)
        Corners (col, row), 0-based, pixel centres at integers.
    object_mm : numpy.ndarray, shape (N, 3)
        The matching board points (z = 0).
    name : str
        Where the view came from (file name), for reports.
    """

    pixels: np.ndarray
    object_mm: np.ndarray
    name: str = ""


def parse_board(text: str) -> tuple[int, int]:
    """``"8x6"`` -> (8, 6): inner corners per row, per column."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"board: expected COLSxROWS inner corners such as 8x6, got {text!r}"
                         ) from None
    if cols < 2 or rows < 2:
        raise ValueError(f"board: expected at least 2x2 inner corners, got {text!r}")
    return cols, rows


def _grey8(img: np.ndarray) -> np.ndarray:
    """The image as 8-bit grey, the only depth OpenCV's board finders take.

    :func:`~pipestitch.camera.frames.to_grey` (an integer range to [0, 1], a float
    image as it is), then stretched so that 1 (a float image: its maximum) is 255,
    rounded to the nearest level. A grey 8-bit image comes back unchanged; a 16-bit
    one as ``rint(value / 257)``.
    """
    arr = np.asarray(img)
    grey = to_grey(arr)
    top = 1.0 if arr.dtype.kind in "ui" else float(grey.max() or 1.0)
    return np.clip(np.rint(grey.astype(np.float64) * (255.0 / top)), 0, 255).astype(np.uint8)


def _refine(grey: np.ndarray, corners: np.ndarray, cols: int) -> np.ndarray:
    """``cv2.cornerSubPix`` with a window a third of the local corner spacing.

    On strongly distorted (curved) squares the sector detector's corners are biased
    towards the image centre by 0.1-0.2 px (measured on rendered fisheye views); a
    saddle-point refinement in a window small enough to keep the edges nearly
    straight halves that error.
    """
    grid = corners.reshape(-1, cols, 2)
    steps = np.concatenate([np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel(),
                            np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel()])
    half = int(np.clip(np.floor(np.min(steps) / 3), 2, 10))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    start = corners.astype(np.float32).reshape(-1, 1, 2).copy()
    return cv2.cornerSubPix(grey, start, (half, half), (-1, -1), criteria).reshape(-1, 2)


def _find(grey: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    size = (cols, rows)
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    ok, corners = cv2.findChessboardCornersSB(grey, size, flags=flags)
    if not ok:
        ok, corners = cv2.findChessboardCorners(
            grey, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    return _refine(grey, corners.reshape(-1, 2), cols).astype(np.float64)


def detect_board(img: np.ndarray, board: Board, *, name: str = "") -> BoardView | None:
    """Find the board's inner corners in an image.

    Parameters
    ----------
    img : numpy.ndarray
        Grey or BGR image, 8 or 16 bit (or float).
    board : Board
        The board to look for; the rotated orientation is tried too.
    name : str
        Label carried into the view (the file name).

    Returns
    -------
    BoardView or None
        None when the whole board is not found (a partial board is not used).
    """
    grey = _grey8(img)
    for candidate in (board, board.transposed()):
        pixels = _find(grey, candidate.cols, candidate.rows)
        if pixels is not None:
            return BoardView(pixels, candidate.object_points(), name)
        if board.cols == board.rows:
            break
    return None
