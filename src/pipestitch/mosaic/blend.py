"""Stitching: strips on one (theta, z) canvas with exposure compensation and feathering.

The canvas follows SPEC's wall-image convention: row i at theta = i·deg_per_px
(relative to the roll reference), column j at z = z0_mm + j·mm_per_px_axial. Every frame is
unwrapped straight onto the canvas nodes it covers (its grid is the canvas' shifted by
the frame's solved z and roll, sub-pixel), so the image is resampled once. Before
blending each strip is divided by its LED shading and the lens' fall-off learned from the
run (:mod:`pipestitch.mosaic.flat_field`), and scaled by a gain matched to what the canvas
already holds in the overlap (exposure changes); strips are blended with weights =
quality x a feather that falls to 0 at the edges of their valid region, so seams do not
show. Rows wrap around the pipe, so theta = 0/360 is not a seam.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse

from pipestitch.geometry import WallGrid
from pipestitch.imaging import median
from pipestitch.mosaic._blend_kernels import (
    accumulate_strip,
    feathered_weight,
    gain_ratios,
    shaded_albedo,
)
from pipestitch.mosaic.unwrap import Strip

__all__ = ["Canvas", "Overview", "ShadedStrip", "canvas_grid", "frame_grid", "overview_factor",
           "shade"]

FEATHER_PX = 24       # width of the feather at a strip's edges (output pixels)
GAIN_LIMITS = (0.5, 2.0)
GAIN_DEADBAND = 0.05  # relative: see Canvas._gain
GAIN_MIN_NODES = 500  # overlap nodes a gain needs (else 1)
GAIN_STRIDE = 2       # the gain's medians read every 2nd row and column of the overlap


def canvas_grid(z_mm: np.ndarray, window_mm: tuple[float, float], strip: WallGrid) -> WallGrid:
    """Canvas covering every placed frame's window, on the strips' scale.

    z0 is a whole number of pixels so that columns fall on round positions.
    """
    z = z_mm[np.isfinite(z_mm)]
    if z.size == 0:
        raise ValueError("canvas_grid: no placed frame")
    mm = strip.mm_per_px_axial
    z0 = np.floor((z.min() + window_mm[0]) / mm) * mm
    z1 = z.max() + window_mm[1]
    return WallGrid(radius_mm=strip.radius_mm, deg_per_px=strip.deg_per_px, mm_per_px_axial=mm,
                    z0_mm=float(z0), n_cols=int(np.ceil((z1 - z0) / mm)) + 1)


def frame_grid(canvas: WallGrid, z_mm: float, roll_deg: float,
               window_mm: tuple[float, float]) -> tuple[WallGrid, int]:
    """The frame's own (theta, z) grid of the canvas nodes in its window, and its first column.

    A canvas node (theta_c, z_c) is the frame's (theta_c - roll, z_c - z) (SPEC pose).
    """
    mm = canvas.mm_per_px_axial
    j0 = max(0, int(np.ceil((z_mm + window_mm[0] - canvas.z0_mm) / mm)))
    j1 = min(canvas.n_cols - 1, int(np.floor((z_mm + window_mm[1] - canvas.z0_mm) / mm)))
    grid = WallGrid(radius_mm=canvas.radius_mm, deg_per_px=canvas.deg_per_px, mm_per_px_axial=mm,
                    z0_mm=canvas.z0_mm + j0 * mm - z_mm, n_cols=max(1, j1 - j0 + 1),
                    theta0_deg=-roll_deg)
    return grid, j0


PROFILE_FRAMES = 500


def profile_step(n_frames: int) -> int:
    """Every how many frames the flat field (:mod:`pipestitch.mosaic.flat_field`) takes
    one: ≤ ``PROFILE_FRAMES`` frames of a run of ``n_frames``, evenly spaced (a pass keeps
    only their ring levels and overlap ratios, so its memory does not grow with the run)."""
    return max(1, -(-n_frames // PROFILE_FRAMES))


def _edge_distance(valid: np.ndarray) -> np.ndarray:
    """Distance (px) of every node to the edge of the valid region, on the strip wrapped
    by FEATHER_PX rows (rows wrap around the pipe) and padded by a column each side (the
    strip's z ends are edges too): the feather rises from 0 there to 1 FEATHER_PX
    inside (:func:`~pipestitch.mosaic._blend_kernels.feathered_weight`)."""
    pad = FEATHER_PX
    wrapped = np.concatenate([valid[-pad:], valid, valid[:pad]]).astype(np.uint8, copy=False)
    return cv2.distanceTransform(np.pad(wrapped, ((0, 0), (1, 1))), cv2.DIST_L2, 5)


@dataclass(frozen=True)
class ShadedStrip:
    """A strip ready to blend (:func:`shade`).

    ``albedo``: values divided by shading and vignetting, float32, 0 where there is no
    data; ``weight``: blend weight (quality x feather), float32, 0 where there is no data.
    """

    albedo: np.ndarray
    weight: np.ndarray


def shade(strip: Strip) -> ShadedStrip:
    """Divide out the strip's shading (the LED's, times the lens' fall-off,
    :mod:`pipestitch.mosaic.flat_field`) and weigh every node by its quality times the
    feather (see :class:`Canvas`)."""
    if strip.shading.shape != strip.values.shape or strip.weight.shape != strip.values.shape:
        raise ValueError(f"shade: shading {strip.shading.shape} and weight "
                         f"{strip.weight.shape} must be the values' {strip.values.shape}")
    albedo, valid = shaded_albedo(strip.values, strip.shading, strip.weight)
    return ShadedStrip(albedo, feathered_weight(strip.weight, _edge_distance(valid), valid,
                                                FEATHER_PX))


class Canvas:
    """Accumulates weighted strips over a window of columns that slides along the run.

    Only the columns between the first not yet released (:meth:`release`) and the last
    reached by a strip are held, so memory is set by how far the strips of the frames
    in flight spread along z, not by the length of the run. :meth:`image` gives the
    whole blended mosaic of a canvas nothing was released from.
    """

    def __init__(self, grid: WallGrid) -> None:
        self.grid = grid
        self.first = 0                      # canvas column of the window's column 0
        self.total = np.zeros((grid.n_rows, 0), np.float32)
        self.weights = np.zeros((grid.n_rows, 0), np.float32)

    def add(self, strip: Strip, column: int) -> float:
        """Blend ``strip`` (its grid's columns start at canvas ``column``; its shading is
        the brightness of a unit albedo); returns the exposure gain applied. Same as
        ``blend(shade(strip), column)``.

        Raises
        ------
        ValueError
            If the strip reaches columns already released.
        """
        return self.blend(shade(strip), column)

    def blend(self, shaded: ShadedStrip, column: int) -> float:
        """Blend a strip made ready by :func:`shade` (its columns start at canvas
        ``column``); returns the exposure gain applied.

        Only the gain and the sums depend on the canvas: the rest of the work per strip
        is in :func:`shade`, which worker threads run side by side while strips are
        blended here in order.

        Raises
        ------
        ValueError
            If the strip reaches columns already released.
        """
        if column < self.first:
            raise ValueError(f"canvas columns before {self.first} were released; a strip "
                             f"starts at {column}")
        width = shaded.albedo.shape[1]
        self._reach(column + width)
        cols = slice(column - self.first, column - self.first + width)
        if (cols.stop > self.total.shape[1] or shaded.weight.shape != shaded.albedo.shape
                or shaded.albedo.shape[0] != self.grid.n_rows):
            raise ValueError(f"strip of {shaded.albedo.shape} at column {column}: the canvas "
                             f"has {self.grid.n_rows} rows and {self.grid.n_cols} columns "
                             f"(and the weight must match the strip)")
        gain = self._gain(shaded.albedo, shaded.weight, cols)
        accumulate_strip(self.total, self.weights, cols.start, shaded.albedo, shaded.weight,
                         gain)
        return gain

    def _reach(self, end: int) -> None:
        """Grow the window to canvas column ``end`` (exclusive), in steps of 512 columns."""
        need = min(end, self.grid.n_cols) - self.first
        if need <= self.total.shape[1]:
            return
        width = min(max(need, self.total.shape[1] + 512), self.grid.n_cols - self.first)
        grow = ((0, 0), (0, width - self.total.shape[1]))
        self.total, self.weights = np.pad(self.total, grow), np.pad(self.weights, grow)

    def _gain(self, values: np.ndarray, weight: np.ndarray, cols: slice) -> float:
        """Median over the nodes where both have data of the canvas over the strip (a
        statistic of hundreds of thousands of nodes: every ``GAIN_STRIDE``-th row and
        column of them is as good, at a quarter of the cost).

        Node by node, so that the wall's pattern cancels: a ratio of the two medians
        would follow whichever tone of a two-tone wall (a chart, a painted mark) holds
        the majority in the overlap. A ratio within ``GAIN_DEADBAND`` of 1 is taken as
        1: each strip's ratio carries a small bias of its own (the two views resolve
        the wall differently, and the fall-off is known to a percent or so), which a
        chain of gains would add up into a brightness drift along the run; a change of
        the camera's exposure shows as a step beyond it.
        """
        s = GAIN_STRIDE
        ratios = np.empty(-(-values.shape[0] // s) * -(-values.shape[1] // s), np.float32)
        found = gain_ratios(self.total, self.weights, cols.start, values, weight, s, ratios)
        if found * s * s < GAIN_MIN_NODES:
            return 1.0
        ratio = median(ratios[:found])
        if not (math.isfinite(ratio) and ratio > 0) or abs(math.log(ratio)) <= math.log1p(
                GAIN_DEADBAND):
            return 1.0   # (no ratio: the canvas holds black there, as a frame of no light)
        return float(np.clip(ratio, *GAIN_LIMITS))

    def release(self, end: int | None = None) -> tuple[int, np.ndarray, np.ndarray] | None:
        """Blend and give up the columns before canvas column ``end`` (default: all).

        Returns ``(first column, mosaic, weights)`` of those columns (float, NaN where no
        data), or None when there are none; later strips must start at ``end`` or after.
        """
        end = self.grid.n_cols if end is None else min(end, self.grid.n_cols)
        if end <= self.first:
            return None
        n = end - self.first
        self._reach(end)
        total, weights = self.total[:, :n], self.weights[:, :n].copy()
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(weights > 1e-6, total / weights, np.nan).astype(np.float32)
        first = self.first
        self.total, self.weights = self.total[:, n:].copy(), self.weights[:, n:].copy()
        self.first = end
        return first, out, weights

    def image(self) -> tuple[np.ndarray, np.ndarray]:
        """The whole blended mosaic (float, NaN where no data) and the weight per node.

        Raises
        ------
        ValueError
            If columns were released already.
        """
        if self.first:
            raise ValueError("image(): columns were released already")
        released = self.release()
        assert released is not None
        _, mosaic, weights = released
        return mosaic, weights


def overview_factor(n_rows: int, n_cols: int, max_pixels: int) -> int:
    """Smallest integer reduction that brings an n_rows x n_cols mosaic within max_pixels."""
    f = 1
    while math.ceil(n_rows / f) * math.ceil(n_cols / f) > max_pixels:
        f += 1
    return f


def _row_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) box weights resampling rows that wrap around the pipe.

    Output row i is centred on input row i·n_in/n_out (so it stays at theta = i·deg_per_px
    of its own grid) and averages the input rows its box of n_in/n_out rows covers.
    """
    s = n_in / n_out
    d = np.arange(n_in)[None, :] - (np.arange(n_out) * s)[:, None]
    d = (d + n_in / 2) % n_in - n_in / 2          # signed distance around the circle
    return np.clip(np.minimum(d + 0.5, s / 2) - np.maximum(d - 0.5, -s / 2), 0, None)


class Overview:
    """A reduced copy of an 8-bit mosaic (0 = no data) built from its column blocks.

    The reduction ``factor`` f is the smallest integer that keeps the copy within
    ``max_pixels``. Columns are averaged in groups of f; rows are box-resampled around
    the circumference to round(n_rows / f) rows, row i staying at theta = i x its own
    deg_per_px (SPEC's wall-image convention). A pixel is data when at least half of
    what it averages is. Only the copy and fewer than f columns are held.
    """

    def __init__(self, grid: WallGrid, max_pixels: int = 16_000_000) -> None:
        self.factor = overview_factor(grid.n_rows, grid.n_cols, max_pixels)
        f, mm = self.factor, grid.mm_per_px_axial
        n_rows = grid.n_rows if f == 1 else max(8, round(grid.n_rows / f))
        n_cols = math.ceil(grid.n_cols / f)
        # Column j' averages canvas columns f j' .. f j' + f - 1: its centre is (f - 1)/2 on.
        self.grid = WallGrid(radius_mm=grid.radius_mm, deg_per_px=360.0 / n_rows,
                             mm_per_px_axial=f * mm, z0_mm=grid.z0_mm + (f - 1) / 2 * mm,
                             n_cols=n_cols)
        self.image = np.zeros((n_rows, n_cols), np.uint8)
        self._rows: scipy.sparse.csr_array | None = None
        if f > 1:
            # each output row averages ~f + 1 input rows: a sparse product, summed in one
            # order (a dense sgemm's blocking, and so its last bits, follows the threads
            # BLAS has at the time; and it multiplies all the zeros)
            rows = _row_weights(grid.n_rows, n_rows).astype(np.float32)
            self._rows = scipy.sparse.csr_array(rows)
            self._row_totals = rows.sum(axis=1, keepdims=True)
        self._carry = np.zeros((grid.n_rows, 0), np.uint8)
        self._col = 0

    def push(self, block: np.ndarray) -> None:
        """The mosaic's next columns (uint8, left to right)."""
        data = np.concatenate([self._carry, block], axis=1) if self._carry.size else block
        whole = data.shape[1] // self.factor * self.factor
        self._emit(data[:, :whole])
        self._carry = data[:, whole:].copy()

    def finish(self) -> np.ndarray:
        """Reduce the last (partial) group of columns; returns the overview image."""
        self._emit(self._carry)
        self._carry = self._carry[:, :0]
        return self.image

    def _emit(self, data: np.ndarray) -> None:
        if data.shape[1] == 0:
            return
        f = self.factor
        if self._rows is None:
            self.image[:, self._col:self._col + data.shape[1]] = data
            self._col += data.shape[1]
            return
        starts = np.arange(0, data.shape[1], f)
        valid = (data > 0).astype(np.float32)
        sums = self._rows @ np.add.reduceat(data.astype(np.float32), starts, axis=1)
        counts = self._rows @ np.add.reduceat(valid, starts, axis=1)
        widths = np.diff(np.append(starts, data.shape[1])).astype(np.float32)
        enough = counts >= 0.5 * self._row_totals * widths[None, :]
        out = np.where(enough, np.rint(sums / np.maximum(counts, 1e-6)), 0)
        self.image[:, self._col:self._col + starts.size] = np.clip(out, 0, 255).astype(np.uint8)
        self._col += starts.size
