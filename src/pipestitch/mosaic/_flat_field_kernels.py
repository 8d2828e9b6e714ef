"""Compiled inner loop of the flat field (numba): the fall-off at every strip node.

Why hand-written: numpy needs five temporary arrays of the strip's size for the radius,
the ring position, its whole and fractional parts and the interpolation; this is one
pass (a stitch strip is about a million nodes).

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def fall_off_at(map_x: np.ndarray, map_y: np.ndarray, centre_col: float, centre_row: float,
                ring_px: float, level: np.ndarray) -> np.ndarray:
    """``level`` (per ring centre, rings ``ring_px`` wide from the centre) interpolated
    linearly at the radius of every pixel position, the end rings' values beyond them
    (float32, the maps' shape)."""
    n = level.shape[0]
    out = np.empty(map_x.shape, np.float32)
    for i in range(map_x.shape[0]):
        for j in range(map_x.shape[1]):
            dx = np.float64(map_x[i, j]) - centre_col
            dy = np.float64(map_y[i, j]) - centre_row
            pos = min(max(np.sqrt(dx * dx + dy * dy) / ring_px - 0.5, 0.0), n - 1.0)
            low = min(int(pos), n - 2)
            frac = pos - low
            out[i, j] = F32(level[low] * (1.0 - frac) + level[low + 1] * frac)
    return out
