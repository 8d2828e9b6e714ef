"""Compiled inner loops of the laser-ring search (numba): division by the wall's
reflectance and the strongest ridge peaks along each ray.

Why hand-written: both run on whole polar frames, once per laser frame; as numpy
expressions each allocates several frame-sized temporaries, and the division by the
reflectance needs its broad mean (two box blurs) first: fused, a row's samples are
read once while they are in the cache.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

F32 = np.float32


ROWS = 4   # rays whose box sums run side by side: _box_means' four named sums (keep 4)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def flatten_by_reflectance(polar: np.ndarray, local: np.ndarray, box: int, floor: float,
                           min_relative: float) -> np.ndarray:
    """``polar / max(local / broad, min_relative)`` where the wall is bright enough, else 0.

    ``broad`` is ``local``'s mean over ``box`` (odd) samples along each row, taken
    twice: ``cv2.blur`` with a (box, 1) kernel and ``BORDER_REPLICATE``, twice, as
    OpenCV computes it for float32 (running sums in float64, each mean rounded to
    float32). Bright enough: ``local > floor·broad`` and ``broad > 0``; the division
    in float32, as the numpy expression. One pass over the rows, ``ROWS`` at a time,
    instead of two blurs and a division over the whole polar frame (4.3 against 2.0
    ms for 1440 x 876 samples, when the box sums were kept in an array).
    """
    n_rows, n = polar.shape
    out = np.empty(polar.shape, np.float32)
    once = np.empty((ROWS, n), np.float32)
    broad = np.empty((ROWS, n), np.float32)
    f, m = F32(floor), F32(min_relative)
    for first in range(0, n_rows, ROWS):
        _box_means(local, first, box // 2, once)
        _box_means(once, 0, box // 2, broad)
        for r in range(min(ROWS, n_rows - first)):
            for j in range(n):
                b, v = broad[r, j], local[first + r, j]
                bright = v > f * b and b > F32(0)
                out[first + r, j] = polar[first + r, j] / max(v / b, m) if bright else F32(0)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _box_means(src: np.ndarray, first: int, half: int, dst: np.ndarray) -> None:
    """Rows ``first .. first + 3`` of ``src`` (the last row again past the end): the
    mean over ``2 half + 1`` samples about each, the border replicated, into ``dst``
    (float64 running sums: add the sample entering, subtract the one leaving).

    Four rows (``ROWS``) in four named sums: independent chains of additions the
    processor overlaps (a 1440 x 578 polar frame's division 3.2 -> 1.6 ms against sums
    in an array indexed by a row count; the same values).
    """
    n, last = src.shape[1], src.shape[0] - 1
    scale = 1.0 / (2 * half + 1)
    s0, s1 = src[min(first, last)], src[min(first + 1, last)]
    s2, s3 = src[min(first + 2, last)], src[min(first + 3, last)]
    d0, d1, d2, d3 = dst[0], dst[1], dst[2], dst[3]
    t0 = t1 = t2 = t3 = 0.0
    for k in range(-half, half + 1):
        at = min(max(k, 0), n - 1)
        t0 += s0[at]
        t1 += s1[at]
        t2 += s2[at]
        t3 += s3[at]
    d0[0], d1[0], d2[0], d3[0] = t0 * scale, t1 * scale, t2 * scale, t3 * scale
    for j in range(1, n):
        enter, leave = min(j + half, n - 1), max(j - half - 1, 0)
        t0 += np.float64(s0[enter]) - np.float64(s0[leave])
        t1 += np.float64(s1[enter]) - np.float64(s1[leave])
        t2 += np.float64(s2[enter]) - np.float64(s2[leave])
        t3 += np.float64(s3[enter]) - np.float64(s3[leave])
        d0[j], d1[j], d2[j], d3[j] = t0 * scale, t1 * scale, t2 * scale, t3 * scale


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
