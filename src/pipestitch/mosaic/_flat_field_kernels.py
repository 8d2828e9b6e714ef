"""Compiled inner loops of the flat field (numba): the fall-off at every strip node and
every node's ring of image radius.

Why hand-written: numpy needs five temporary arrays of the strip's size for the radius,
the ring position, its whole and fractional parts and the interpolation; this is one
pass (a stitch strip is about a million nodes).

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def fall_off_at(map_x: np.ndarray, map_y: np.ndarray, centre_col: float, centre_row: float,
                ring_px: float, level: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``level`` (per ring centre, rings ``ring_px`` wide from the centre) interpolated
    linearly at the radius of every pixel position, the end rings' values beyond them
    (float32, the maps' shape); multiplied by ``times`` (float32, the maps' shape; empty:
    not) as float32 arrays multiply.

    Row by row: the ring positions first (a loop the compiler vectorises), then the
    look-ups (2x faster than both in one loop; the same values).
    """
    n = level.shape[0]
    out = np.empty(map_x.shape, np.float32)
    pos = np.empty(map_x.shape[1])
    scaled = times.size > 0
    for i in range(map_x.shape[0]):
        _ring_positions(map_x[i], map_y[i], centre_col, centre_row, ring_px, n - 1.0, pos)
        row = out[i]
        for j in range(map_x.shape[1]):
            low = min(int(pos[j]), n - 2)
            frac = pos[j] - low
            row[j] = F32(level[low] * (1.0 - frac) + level[low + 1] * frac)
        if scaled:
            for j in range(map_x.shape[1]):
                row[j] = times[i, j] * row[j]
    return out


@numba.njit(cache=True, nogil=True)
def _ring_positions(map_x: np.ndarray, map_y: np.ndarray, centre_col: float,
                    centre_row: float, ring_px: float, last: float, pos: np.ndarray) -> None:
    """Each position's distance from the centre in rings, less half a ring, clipped to
    [0, ``last``] (float64)."""
    for j in range(map_x.shape[0]):
        dx = np.float64(map_x[j]) - centre_col
        dy = np.float64(map_y[j]) - centre_row
        pos[j] = min(max(np.sqrt(dx * dx + dy * dy) / ring_px - 0.5, 0.0), last)


@numba.njit(cache=True, nogil=True)
def ring_index(map_x: np.ndarray, map_y: np.ndarray, centre_col: float, centre_row: float,
               rings_per_px: float, n_rings: int) -> np.ndarray:
    """The ring of image radius of every pixel position (int16, -1 beyond the last ring):
    ``int32(radius · rings_per_px)`` in float32, the radius ``hypot`` of the float32
    offsets from the centre in float64, rounded once to float32 (C's ``hypotf``)."""
    out = np.empty(map_x.shape, np.int16)
    cx, cy, k = F32(centre_col), F32(centre_row), F32(rings_per_px)
    for i in range(map_x.shape[0]):
        for j in range(map_x.shape[1]):
            dx, dy = np.float64(map_x[i, j] - cx), np.float64(map_y[i, j] - cy)
            ring = np.int32(F32(np.sqrt(dx * dx + dy * dy)) * k)
            out[i, j] = ring if 0 <= ring < n_rings else -1
    return out
