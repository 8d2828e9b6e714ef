"""Defects of a mosaic that arrives as column blocks (a long run, never held whole).

:func:`pipestitch.measure.defects.find_defects` is run on overlapping windows of
``core_cols`` columns with ``margin`` columns either side; a defect belongs to the
window whose core holds its centre, and the margins are wider than the running-median
background window and than a defect, so each defect is found and sized whole exactly
once. Each window thresholds against its own noise level (a long run's texture and
lighting change along the pipe). A mosaic no longer than one core plus a margin is
measured in one piece, exactly as ``find_defects`` on the whole image.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from pipestitch.geometry.wall_grid import WallGrid
from pipestitch.measure.defects import Defect, background_mm, find_defects

__all__ = ["BlockDefects"]

CORE_COLS = 2048
MARGIN_WINDOWS = 4   # margin in background windows (2 radii): the window and the largest defect


class BlockDefects:
    """Push column blocks left to right (:meth:`push`), then :meth:`finish`.

    Parameters
    ----------
    grid : WallGrid
        The whole mosaic's grid (column 0 at ``z0_mm``; its ``n_cols`` is not used:
        each window is measured on this grid cut to its own columns).
    up_theta_deg : float
        Theta of 12 o'clock (as in ``find_defects``).
    core_cols : int, optional
        Columns each window owns (default ``CORE_COLS``).
    """

    def __init__(self, grid: WallGrid, *, up_theta_deg: float = 270.0,
                 core_cols: int | None = None) -> None:
        self.grid, self.up = grid, up_theta_deg
        self.core = core_cols or CORE_COLS
        self.margin = math.ceil(MARGIN_WINDOWS * background_mm(grid) / grid.mm_per_px_axial)
        self.defects: list[Defect] = []
        self._buffer = np.zeros((0, 0), np.float32)
        self._first = 0          # mosaic column of the buffer's column 0
        self._owned = 0          # first column not yet owned by a measured window

    def push(self, col0: int, block: np.ndarray) -> None:
        """The next columns (float, NaN where no data), starting at mosaic column col0."""
        if self._buffer.size == 0:
            self._buffer, self._first = np.asarray(block, np.float32), col0
        else:
            if col0 != self._first + self._buffer.shape[1]:
                raise ValueError(f"expected the block at column "
                                 f"{self._first + self._buffer.shape[1]}, got {col0}")
            self._buffer = np.concatenate([self._buffer, block], axis=1)
        while self._first + self._buffer.shape[1] >= self._owned + self.core + self.margin:
            self._measure(self._owned + self.core)

    def finish(self) -> list[Defect]:
        """Measure what is left; all defects sorted by z."""
        if self._buffer.size:
            self._measure(self._first + self._buffer.shape[1])
        return sorted(self.defects, key=lambda d: d.z_mm)

    def _measure(self, owned_end: int) -> None:
        """Window over [owned - margin, owned_end + margin); keep defects centred in
        [owned, owned_end); then drop the columns no later window needs."""
        start = max(self._first, self._owned - self.margin)
        stop = min(self._first + self._buffer.shape[1], owned_end + self.margin)
        g = self.grid
        window = self._buffer[:, start - self._first:stop - self._first]
        z0 = g.z0_mm + start * g.mm_per_px_axial
        found = find_defects(window, replace(g, z0_mm=z0, n_cols=window.shape[1]),
                             up_theta_deg=self.up)
        lo, hi = (g.z0_mm + (c - 0.5) * g.mm_per_px_axial for c in (self._owned, owned_end))
        self.defects += [d for d in found if lo <= d.z_mm < hi]
        self._owned = owned_end
        keep_from = max(self._first, owned_end - self.margin)
        self._buffer = self._buffer[:, keep_from - self._first:].copy()
        self._first = keep_from
