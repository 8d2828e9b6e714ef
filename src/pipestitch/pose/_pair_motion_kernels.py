"""Compiled inner loop of the LED frame's shift along the ring (numba): each sector's
correlation of the line's brightness with the wall's reflectance moved by each shift
and turn.

Why hand-written: for every shift and turn the reflectance is read along the ring,
high-passed along it (two box means) and summed per sector; as numpy expressions each
(turn, shift) row is gathered, blurred, converted and multiplied through several
temporaries, and the sums are products with a sector-membership matrix: 6.1-7.1 ms
of a moving half-size frame's shift against 3.4-3.9 ms fused, where a row's samples are
read once while they are in the cache.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)
from pipestitch.pose._ring_kernels import ROWS, _box_means, border_index

# ROWS shifts' rows are summed side by side (the ring's box means' four named sums)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def sector_correlations(logs: np.ndarray, first_col: int, n_samples: int, read: np.ndarray,
                        at: np.ndarray, bounds: np.ndarray, centred: np.ndarray,
                        spread: np.ndarray, shifts: np.ndarray, high_pass: int,
                        smooth: int) -> np.ndarray:
    """(sectors, turns, shifts) correlation of a line's brightness with the reflectance
    read along the ring moved by each shift along the rays and each turn across them.

    Parameters
    ----------
    logs : numpy.ndarray, shape (rows, m), float32
        The log reflectance (LED frame on the polar grid) of the rays read, over samples
        ``first_col`` to ``first_col + m - 1``: each ``clip(at + shift, 0,
        n_samples - 1)`` must lie in it.
    first_col, n_samples : int
        The first sample ``logs`` holds, and the rays' length.
    read : numpy.ndarray of int64, shape (turns, ring rays)
        For each turn, the row of ``logs`` read for each ray of the ring (the ray turned).
    at : numpy.ndarray of int64
        The sample of the line's peak on each ray of the ring (rays increasing).
    bounds : numpy.ndarray of int64, shape (n_sectors + 1,)
        Where each sector's rays start in ``rays`` (and where the last ends).
    centred : numpy.ndarray of float64
        The line's brightness along the ring, each sector's mean taken off.
    spread : numpy.ndarray of float64, shape (n_sectors,)
        Its variance in each sector.
    shifts : numpy.ndarray of int64
        Samples along the rays (a ray's ends are repeated beyond it).
    high_pass, smooth : int
        Box lengths along the ring (odd): the running mean taken off, then the running
        mean taken (1: none); as ``cv2.blur`` computes them for float32 with
        ``BORDER_REFLECT``, bitwise.

    Returns
    -------
    numpy.ndarray of float64
        The correlations: each sector's covariance over its variances' root, the
        reflectance's moments over the sector's rays (NaN where they vanish).

    ``ROWS`` shifts at a time: their running sums and sector sums are independent
    chains of additions that the processor overlaps (4.3 -> 3.2 ns a sample).
    """
    n_turns, size = read.shape
    out = np.empty((bounds.size - 1, n_turns, shifts.size))
    rows = np.empty((ROWS, size), np.float32)
    means = np.empty((ROWS, size), np.float32)
    for ti in range(n_turns):
        turned = read[ti]
        for si in range(0, shifts.size, ROWS):
            for r in range(ROWS):   # past the last shift: the last again
                shift = shifts[min(si + r, shifts.size - 1)]
                for i in range(size):
                    rows[r, i] = logs[turned[i],
                                      min(max(at[i] + shift, 0), n_samples - 1) - first_col]
            row_means(rows, high_pass, means)
            for r in range(ROWS):
                for i in range(size):
                    rows[r, i] -= means[r, i]
            if smooth > 1:
                row_means(rows, smooth, means)
                _sector_sums(means, bounds, centred, spread, out[:, ti, si:si + ROWS])
            else:
                _sector_sums(rows, bounds, centred, spread, out[:, ti, si:si + ROWS])
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sector_sums(rows: np.ndarray, bounds: np.ndarray, centred: np.ndarray,
                 spread: np.ndarray, out: np.ndarray) -> None:
    """Each sector's correlation of ``rows`` (``ROWS``, float32) with ``centred`` into
    ``out`` (sectors, <= ``ROWS``): float64 sums over the sector's rays, in order."""
    r0, r1, r2, r3 = rows[0], rows[1], rows[2], rows[3]
    for k in range(bounds.size - 1):
        a0 = a1 = a2 = a3 = 0.0   # sums
        b0 = b1 = b2 = b3 = 0.0   # sums of squares
        c0 = c1 = c2 = c3 = 0.0   # sums of products with the line
        for i in range(bounds[k], bounds[k + 1]):
            line = centred[i]
            w0, w1, w2, w3 = (np.float64(r0[i]), np.float64(r1[i]), np.float64(r2[i]),
                              np.float64(r3[i]))
            a0 += w0
            a1 += w1
            a2 += w2
            a3 += w3
            b0 += w0 * w0
            b1 += w1 * w1
            b2 += w2 * w2
            b3 += w3 * w3
            c0 += w0 * line
            c1 += w1 * line
            c2 += w2 * line
            c3 += w3 * line
        count = bounds[k + 1] - bounds[k]
        sums = ((a0, b0, c0), (a1, b1, c1), (a2, b2, c2), (a3, b3, c3))
        for r in range(out.shape[1]):
            a, b, c = sums[r]
            average = a / count
            out[k, r] = (c / count) / np.sqrt((b / count - average * average) * spread[k])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def row_means(src: np.ndarray, length: int, dst: np.ndarray) -> None:
    """``cv2.blur`` of each of the ``ROWS`` float32 rows of ``src`` with a
    (``length``, 1) kernel and ``BORDER_REFLECT``, into ``dst``, bitwise as OpenCV
    computes it: float64 sums of ``length`` samples (for 3 and 5 each written out left
    to right, longer boxes as running sums that add the difference of the sample
    entering and the one leaving), times 1 / ``length``, rounded to float32. ``length``
    odd (centred boxes only); 1 copies.

    The running sums are the ring division's, the four rows side by side
    (:func:`pipestitch.pose._ring_kernels._box_means`, its border reflected).
    """
    if length % 2 == 0:
        raise ValueError("row_means: the box length must be odd")
    if length > 5:
        _box_means(src, np.int64(0), length // 2, dst, np.bool_(True))
        return
    for r in range(ROWS):
        _short_means(src[r], length // 2, dst[r])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _short_means(src: np.ndarray, half: int, dst: np.ndarray) -> None:
    """:func:`row_means` of one row for a box of 1, 3 or 5 samples (``half`` 0-2)."""
    n, scale = src.size, 1.0 / (2 * half + 1)
    if half == 0:   # element by element: a slice assignment compiles a shape check
        for j in range(n):
            dst[j] = src[j]
        return
    if half == 1:   # every sample inside the row
        for j in range(1, n - 1):
            dst[j] = ((np.float64(src[j - 1]) + np.float64(src[j]))
                      + np.float64(src[j + 1])) * scale
    else:
        for j in range(2, n - 2):
            dst[j] = ((((np.float64(src[j - 2]) + np.float64(src[j - 1]))
                        + np.float64(src[j])) + np.float64(src[j + 1]))
                      + np.float64(src[j + 2])) * scale
    for j in range(min(half, n)):   # the ends: the border reflected
        dst[j] = _reflected_sum(src, j, half) * scale
    for j in range(max(n - half, half), n):
        dst[j] = _reflected_sum(src, j, half) * scale


@numba.njit(cache=True, nogil=True, inline="always")
def _reflected_sum(src: np.ndarray, j: int, half: int) -> float:
    """The float64 sum of ``src[j - half .. j + half]`` left to right, the border
    reflected (:func:`pipestitch.pose._ring_kernels.border_index`)."""
    n = src.size
    s = np.float64(src[border_index(j - half, n, True)])
    for k in range(1 - half, half + 1):
        s += np.float64(src[border_index(j + k, n, True)])
    return s
