"""Compiled inner loops of the laser-ring search (numba): division by the wall's
reflectance and the strongest ridge peaks along each ray.

Why hand-written: both run on whole polar frames, once per laser frame; as numpy
expressions each allocates several frame-sized temporaries.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def divide_by_reflectance(polar: np.ndarray, local: np.ndarray, broad: np.ndarray,
                          floor: float, min_relative: float) -> np.ndarray:
    """``polar / max(local / broad, min_relative)`` where the wall is bright enough, else 0.

    Bright enough: ``local > floor·broad`` and ``broad > 0``. float32 throughout, as
    the numpy expression it replaces.
    """
    out = np.empty(polar.shape, np.float32)
    f, m = F32(floor), F32(min_relative)
    for i in range(polar.shape[0]):
        for j in range(polar.shape[1]):
            b, v = broad[i, j], local[i, j]
            if v > f * b and b > F32(0):
                out[i, j] = polar[i, j] / max(v / b, m)
            else:
                out[i, j] = F32(0)
    return out


@numba.njit(cache=True, nogil=True)
def ridge_peaks(ridge: np.ndarray, threshold: float,
                count: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` strongest local maxima of each row of ``ridge`` above ``threshold``.

    A local maximum is above its left neighbour and not below its right one, at
    least 2 samples from either end. Returns (index, value), (rows, count), strongest
    first; missing ones have index 0 and value -inf.
    """
    n_rows, n_cols = ridge.shape
    index = np.zeros((n_rows, count), np.int64)
    value = np.full((n_rows, count), -np.inf, np.float32)
    for i in range(n_rows):
        row = ridge[i]
        for j in range(2, n_cols - 2):
            v = row[j]
            if not (v > threshold and v > row[j - 1] and v >= row[j + 1]):
                continue
            if v <= value[i, count - 1]:
                continue
            k = count - 1
            while k > 0 and value[i, k - 1] < v:   # ties: the earlier sample first
                value[i, k] = value[i, k - 1]
                index[i, k] = index[i, k - 1]
                k -= 1
            value[i, k] = v
            index[i, k] = j
    return index, value
