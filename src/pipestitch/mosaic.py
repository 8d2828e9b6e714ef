"""Stitching: strips on one (theta, z) canvas with exposure compensation and feathering.

The canvas follows SPEC's wall-image convention: row i at theta = i·deg_per_px
(relative to the roll reference), column j at z = z0_mm + j·mm_per_px. Every frame is
unwrapped straight onto the canvas nodes it covers (its grid is the canvas' shifted by
the frame's solved z and roll, sub-pixel), so the image is resampled once. Before
blending each strip is divided by its LED shading and the run's vignetting profile,
and scaled by a gain matched to what the canvas already holds in the overlap
(exposure changes); strips are blended with weights = quality x a feather that falls
to 0 at the edges of their valid region, so seams do not show. Rows wrap around the
pipe, so theta = 0/360 is not a seam.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from pipestitch.unwrap import Strip, StripGrid

__all__ = ["Canvas", "canvas_grid", "frame_grid", "vignetting_profile"]

FEATHER_PX = 24       # width of the feather at a strip's edges (output pixels)
GAIN_LIMITS = (0.5, 2.0)


def canvas_grid(z_mm: np.ndarray, window_mm: tuple[float, float], strip: StripGrid) -> StripGrid:
    """Canvas covering every placed frame's window, on the strips' scale.

    z0 is a whole number of pixels so that columns fall on round positions.
    """
    z = z_mm[np.isfinite(z_mm)]
    if z.size == 0:
        raise ValueError("canvas_grid: no placed frame")
    mm = strip.mm_per_px
    z0 = np.floor((z.min() + window_mm[0]) / mm) * mm
    z1 = z.max() + window_mm[1]
    return StripGrid(strip.deg_per_px, mm, float(z0), int(np.ceil((z1 - z0) / mm)) + 1)


def frame_grid(canvas: StripGrid, z_mm: float, roll_deg: float,
               window_mm: tuple[float, float]) -> tuple[StripGrid, int]:
    """The frame's own (theta, z) grid of the canvas nodes in its window, and its first column.

    A canvas node (theta_c, z_c) is the frame's (theta_c - roll, z_c - z) (SPEC pose).
    """
    mm = canvas.mm_per_px
    j0 = max(0, int(np.ceil((z_mm + window_mm[0] - canvas.z0_mm) / mm)))
    j1 = min(canvas.n_cols - 1, int(np.floor((z_mm + window_mm[1] - canvas.z0_mm) / mm)))
    grid = StripGrid(canvas.deg_per_px, mm, canvas.z0_mm + j0 * mm - z_mm, max(1, j1 - j0 + 1),
                     theta0_deg=-roll_deg)
    return grid, j0


def vignetting_profile(column_levels: list[np.ndarray]) -> np.ndarray:
    """Run-level brightness profile along a strip's z (per column), median 1.

    ``column_levels`` holds, per frame, the median over theta of strip / shading for every
    column of the frame's own window grid (NaN where no data). The median over frames
    leaves the lens' vignetting and any light falloff the shading model misses; the
    wall's own albedo averages out because every frame sees a different piece of wall.
    """
    stack = np.array(column_levels, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # columns no frame saw: NaN
        prof = np.nanmedian(stack, axis=0) if stack.size else np.ones(0)
    prof = np.where(np.isfinite(prof) & (prof > 0), prof, np.nan)
    if not np.isfinite(prof).any():
        return np.ones(stack.shape[1] if stack.ndim == 2 else 0)
    prof /= np.nanmedian(prof)
    idx = np.arange(prof.size)
    good = np.isfinite(prof)
    return np.interp(idx, idx[good], prof[good])


def _feather(valid: np.ndarray) -> np.ndarray:
    """0 at the edge of the valid region rising to 1 FEATHER_PX inside (rows wrap)."""
    pad = FEATHER_PX
    wrapped = np.concatenate([valid[-pad:], valid, valid[:pad]]).astype(np.uint8)
    wrapped = np.pad(wrapped, ((0, 0), (1, 1)))  # the strip's z ends are edges too
    dist = cv2.distanceTransform(wrapped, cv2.DIST_L2, 5)[pad:-pad, 1:-1]
    return np.clip(dist / FEATHER_PX, 0, 1).astype(np.float32)


@dataclass
class Canvas:
    """Accumulates weighted strips; :meth:`image` gives the blended mosaic."""

    grid: StripGrid

    def __post_init__(self) -> None:
        shape = (self.grid.n_rows, self.grid.n_cols)
        self.total = np.zeros(shape, np.float32)
        self.weights = np.zeros(shape, np.float32)

    def add(self, strip: Strip, column: int, level: np.ndarray) -> float:
        """Blend ``strip`` (its grid's columns start at canvas ``column``).

        ``level`` (per strip column) times the strip's shading is the brightness of a
        unit albedo; returns the exposure gain applied.
        """
        values = strip.values / np.maximum(strip.shading * level[None, :], 1e-6)
        valid = np.isfinite(values) & (strip.weight > 0)
        weight = np.where(valid, strip.weight * _feather(valid), 0).astype(np.float32)
        cols = slice(column, column + values.shape[1])
        gain = self._gain(values, weight, cols)
        self.total[:, cols] += np.where(valid, values * gain, 0) * weight
        self.weights[:, cols] += weight
        return gain

    def _gain(self, values: np.ndarray, weight: np.ndarray, cols: slice) -> float:
        have = self.weights[:, cols]
        both = (weight > 0.2) & (have > 0.5)
        if both.sum() < 500:
            return 1.0
        current = self.total[:, cols][both] / have[both]
        ratio = np.median(current) / max(float(np.median(values[both])), 1e-9)
        return float(np.clip(ratio, *GAIN_LIMITS))

    def image(self) -> tuple[np.ndarray, np.ndarray]:
        """Blended mosaic (float, NaN where no data) and the total weight per node."""
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(self.weights > 1e-6, self.total / self.weights, np.nan)
        return out.astype(np.float32), self.weights
