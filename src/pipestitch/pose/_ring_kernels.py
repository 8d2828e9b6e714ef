"""Compiled inner loops of the laser-ring search (numba): division by the wall's
reflectance (as the LED frame saw it, or moved to where the laser frame saw it) and the
strongest ridge peaks along each ray.

Why hand-written: both run on whole polar frames, once per laser frame; as numpy
expressions each allocates several frame-sized temporaries, and the division by the
reflectance needs its broad mean (two box blurs) first: fused, a row's samples are
read once while they are in the cache.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

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
    for first in range(0, n_rows, ROWS):
        _box_means(local, first, box // 2, once, np.bool_(False))
        _box_means(once, np.int64(0), box // 2, broad, np.bool_(False))
        _divide(polar, local, first, first, broad, F32(floor), F32(min_relative), out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def flatten_by_moved_reflectance(polar: np.ndarray, local: np.ndarray, along: np.ndarray,
                                 across: np.ndarray, box: int, floor: float,
                                 min_relative: float) -> np.ndarray:
    """:func:`flatten_by_reflectance` with ``local`` read where the laser frame's wall
    is: row ``r`` at ``along[r]`` samples further out on row ``r + across[r]``
    (fractional; rows wrap around, a row's ends are repeated beyond it), by linear
    interpolation in both directions (in float32).

    The same as ``flatten_by_reflectance(polar, LedShift(along, across).apply(local),
    ...)`` (:class:`pipestitch.pose.pair_motion.LedShift`) but for ``cv2.remap``'s
    weights, which it rounds to 1/32 of a sample: bitwise at whole shifts. Each block of
    ``ROWS`` rows is moved into a small buffer and divided while in the cache, instead of
    a moved frame-sized copy read again (a 1440 x 578 polar frame, one thread: 6.1 -> 3.3
    ms; 2.7 ms since :func:`_moved_row` reads a row's inside samples in one vectorised
    loop).
    """
    n_rows, n = polar.shape
    out = np.empty(polar.shape, np.float32)
    moved = np.zeros((ROWS, n), np.float32)
    once = np.empty((ROWS, n), np.float32)
    broad = np.empty((ROWS, n), np.float32)
    for first in range(0, n_rows, ROWS):
        for r in range(min(ROWS, n_rows - first)):
            _moved_row(local, first + r, along[first + r], across[first + r], moved[r])
        _box_means(moved, np.int64(0), box // 2, once, np.bool_(False))
        _box_means(once, np.int64(0), box // 2, broad, np.bool_(False))
        _divide(polar, moved, first, 0, broad, F32(floor), F32(min_relative), out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _moved_row(local: np.ndarray, row: int, along: float, across: float,
               dst: np.ndarray) -> None:
    """Row ``row`` of ``local`` read ``along`` samples further out on row ``row +
    across`` (linear interpolation; rows wrap, a row's ends repeated) into ``dst``.

    The samples whose two columns both lie inside the row are one loop of contiguous
    reads, which LLVM vectorises; only those reading past an end clamp their columns
    (the same arithmetic for every sample; the moved division of a 1440 x 578 polar
    frame 3.9-4.1 -> 2.7-2.8 ms)."""
    n_rows, n = local.shape
    at = row + across
    low = math.floor(at)
    wy = F32(at - low)
    above, below = local[int(low) % n_rows], local[(int(low) + 1) % n_rows]
    first = math.floor(along)
    wx = F32(along - first)
    shift = int(first)
    inside_from = min(max(-shift, 0), n)
    inside_to = max(min(n - 1 - shift, n), inside_from)
    # views from the first inside sample: indices from 0 (numba's wrap-around of
    # negative indices, which an offset index needs, keeps LLVM from vectorising)
    a0, a1 = above[inside_from + shift:], above[inside_from + shift + 1:]
    b0, b1 = below[inside_from + shift:], below[inside_from + shift + 1:]
    out = dst[inside_from:]
    for k in range(inside_to - inside_from):
        top = (F32(1) - wx) * a0[k] + wx * a1[k]
        bottom = (F32(1) - wx) * b0[k] + wx * b1[k]
        out[k] = (F32(1) - wy) * top + wy * bottom
    for j in range(inside_from):
        _moved_sample(above, below, j, shift, wx, wy, dst)
    for j in range(inside_to, n):
        _moved_sample(above, below, j, shift, wx, wy, dst)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _moved_sample(above: np.ndarray, below: np.ndarray, j: int, shift: int, wx: np.float32,
                  wy: np.float32, dst: np.ndarray) -> None:
    """Sample ``j`` of :func:`_moved_row`, its columns clamped to the row."""
    n = above.size
    c0 = min(max(j + shift, 0), n - 1)
    c1 = min(max(j + shift + 1, 0), n - 1)
    top = (F32(1) - wx) * above[c0] + wx * above[c1]
    bottom = (F32(1) - wx) * below[c0] + wx * below[c1]
    dst[j] = (F32(1) - wy) * top + wy * bottom


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _divide(polar: np.ndarray, local: np.ndarray, first: int, local_first: int,
            broad: np.ndarray, f: np.float32, m: np.float32, out: np.ndarray) -> None:
    """Rows ``first ..`` (``ROWS`` of them, fewer at the end) of ``out``: ``polar``
    divided by ``local`` (rows from ``local_first``) over its broad mean ``broad``."""
    n_rows, n = polar.shape
    for r in range(min(ROWS, n_rows - first)):
        for j in range(n):
            b, v = broad[r, j], local[local_first + r, j]
            bright = v > f * b and b > F32(0)
            out[first + r, j] = polar[first + r, j] / max(v / b, m) if bright else F32(0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _box_means(src: np.ndarray, first: int, half: int, dst: np.ndarray,
               reflect: bool) -> None:
    """Rows ``first .. first + 3`` of ``src`` (the last row again past the end): the
    mean over ``2 half + 1`` samples about each into ``dst``, the border replicated
    (``reflect`` False) or reflected (:func:`border_index`), as ``cv2.blur`` computes a
    float32 box of more than 5 samples (float64 running sums: add the sample entering,
    subtract the one leaving).

    Four rows (``ROWS``) in four named sums: independent chains of additions the
    processor overlaps (a 1440 x 578 polar frame's division 3.2 -> 1.6 ms against sums
    in an array indexed by a row count; the same values).

    Callers pass ``first`` and ``reflect`` as values, not constants (``np.int64(0)``,
    ``np.bool_(False)``): numba compiles a kernel called with a constant argument once
    for each constant (its literal type), ~1 s of the set-up's compile each.
    """
    n, last = src.shape[1], src.shape[0] - 1
    scale = 1.0 / (2 * half + 1)
    s0, s1 = src[min(first, last)], src[min(first + 1, last)]
    s2, s3 = src[min(first + 2, last)], src[min(first + 3, last)]
    d0, d1, d2, d3 = dst[0], dst[1], dst[2], dst[3]
    t0 = t1 = t2 = t3 = 0.0
    for k in range(-half, half + 1):
        at = border_index(k, n, reflect)
        t0 += s0[at]
        t1 += s1[at]
        t2 += s2[at]
        t3 += s3[at]
    d0[0], d1[0], d2[0], d3[0] = t0 * scale, t1 * scale, t2 * scale, t3 * scale
    for j in range(1, n):
        enter = border_index(j + half, n, reflect)
        leave = border_index(j - half - 1, n, reflect)
        t0 += np.float64(s0[enter]) - np.float64(s0[leave])
        t1 += np.float64(s1[enter]) - np.float64(s1[leave])
        t2 += np.float64(s2[enter]) - np.float64(s2[leave])
        t3 += np.float64(s3[enter]) - np.float64(s3[leave])
        d0[j], d1[j], d2[j], d3[j] = t0 * scale, t1 * scale, t2 * scale, t3 * scale


@numba.njit(cache=True, nogil=True, inline="always")
def border_index(p: int, n: int, reflect: bool) -> int:
    """Index ``p`` of a row of ``n`` samples, its border replicated (OpenCV's
    ``BORDER_REPLICATE``, ``aaa|abcd|ddd``) or reflected (``BORDER_REFLECT``,
    ``cba|abcd|dcb``, again until inside the row)."""
    if not reflect:
        return min(max(p, 0), n - 1)
    if n == 1:
        return 0
    while p < 0 or p >= n:
        p = -p - 1 if p < 0 else 2 * n - 1 - p
    return p


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


# --- the line's width and the candidates' centroids --------------------------------------
# Both read a short window of each candidate's ray (tens of samples, ~700-2,000 rays a
# frame): as numpy expressions each was a dozen gathers and reductions over (rays,
# window) temporaries (1.3 ms a frame); here one pass a ray. Sums over a window are
# numpy's pairwise sums (:func:`_window_sum`), so the values are the same to the bit.


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _window_sum(values: np.ndarray, zero: float) -> float:
    """``values.sum()`` of a 1-D window as numpy forms it along a contiguous axis:
    sequentially below 8 values, else in 8 interleaved partial sums added as a tree,
    then the remainder, in the type of ``zero`` (the values' own). That is numpy's
    pairwise sum up to its 128-value block, which numpy splits longer runs into: a
    centroid window is 6 line sigmas of samples and longer only for a line of more
    than ~10 px sigma (an image over ~12,900 px wide, or a sigma given so), where the
    sum's last bits may differ from numpy's (a recursion, as numpy's, is not cached
    by numba)."""
    n = values.size
    if n < 8:
        res = zero
        for i in range(n):
            res += values[i]
        return res
    r0, r1, r2, r3 = values[0] + zero, values[1] + zero, values[2] + zero, values[3] + zero
    r4, r5, r6, r7 = values[4] + zero, values[5] + zero, values[6] + zero, values[7] + zero
    i = 8
    while i < n - n % 8:
        r0 += values[i]
        r1 += values[i + 1]
        r2 += values[i + 2]
        r3 += values[i + 3]
        r4 += values[i + 4]
        r5 += values[i + 5]
        r6 += values[i + 6]
        r7 += values[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for k in range(i, n):
        res += values[k]
    return zero + res


@numba.njit(cache=True, nogil=True, error_model="numpy")
def centroids(polar: np.ndarray, smooth: np.ndarray, rows: np.ndarray, idx: np.ndarray,
              half: int, reach: np.ndarray) -> np.ndarray:
    """Each candidate's centroid (samples) above its window's local background.

    The window: samples ``idx - half .. idx + half`` of its row (clamped to the row),
    cut to ``|offset| <= max(reach, 2)``. Background: the lower end value; weights:
    the profile above ``background + 0.3 (smooth peak - background)``, floored at 0
    (float32, as the numpy expressions); the centroid ``idx + sum(w·offset) / sum(w)``
    (float64; ``idx`` where no weight).
    """
    n, n_cols = rows.size, polar.shape[1]
    width = 2 * half + 1
    weight = np.empty(width, np.float32)
    moment = np.empty(width, np.float64)
    out = np.empty(n, np.float64)
    for c in range(n):
        row, at = polar[rows[c]], idx[c]
        first, last = row[min(max(at - half, 0), n_cols - 1)], row[min(at + half, n_cols - 1)]
        base = first if first <= last or first != first else last   # np.minimum
        cut = base + F32(0.3) * (smooth[rows[c], at] - base)
        limit = reach[c] if reach[c] > 2.0 or reach[c] != reach[c] else 2.0   # np.maximum
        for k in range(width):
            v = row[min(max(at - half + k, 0), n_cols - 1)] - cut
            w = v if v >= F32(0) or v != v else F32(0)   # np.clip(., 0, None)
            w *= F32(1) if abs(k - half) <= limit else F32(0)
            weight[k] = w
            moment[k] = np.float64(w) * (k - half)
        total = _window_sum(weight, F32(0))
        out[c] = at + (_window_sum(moment, 0.0) / total if total > F32(0) else 0.0)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def line_widths(polar: np.ndarray, rows: np.ndarray, idx: np.ndarray, half: int) -> np.ndarray:
    """Each candidate's full width at half maximum (samples), NaN where not measured.

    The profile: samples ``idx - half .. idx + half`` of its row (NaN past the row's
    ends); background its 20th percentile (linear interpolation between order
    statistics, as ``numpy.percentile``), peak the largest of the middle five; each
    side's half-maximum crossing interpolated between the last sample above and the
    first below. NaN where a side never falls below half maximum or the peak is not
    above the background. The same float32/float64 arithmetic as the numpy
    expressions it replaces (:func:`pipestitch.pose.ring._line_sigma_px`).
    """
    n, n_cols, width = rows.size, polar.shape[1], 2 * half + 1
    profile = np.empty(width, np.float32)
    smallest = np.empty(width, np.float32)
    out = np.empty(n, np.float64)
    for c in range(n):
        row, at = polar[rows[c]], idx[c]
        finite = np.int64(0)   # a value: a constant 0 compiles _percentile_20 for it too
        for k in range(width):
            col = at - half + k
            profile[k] = row[col] if 0 <= col < n_cols else np.float32(np.nan)
            finite += np.isfinite(profile[k])
        base = _percentile_20(profile, finite, smallest)
        peak = np.float32(np.nan)
        for k in range(half - 2, half + 3):
            if profile[k] == profile[k] and (peak != peak or profile[k] > peak):
                peak = profile[k]
        level = base + (peak - base) / 2
        left = _crossing(profile, level, half, np.int64(-1))   # values: see _box_means
        right = _crossing(profile, level, half, np.int64(1))
        fwhm = left + right
        out[c] = fwhm if np.isfinite(fwhm) and peak > base else np.nan
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _percentile_20(profile: np.ndarray, finite: int, smallest: np.ndarray) -> float:
    """The 20th percentile of a window's ``finite`` finite values (NaN when none): the
    linear interpolation between the two order statistics about rank 0.2 (finite - 1)
    of the values sorted with NaN left out (an infinity sorted among them), as the numpy
    expression it replaces gives it (``numpy.sort`` of the rows, then the two ranks),
    from the smallest values kept sorted in ``smallest`` (scratch)."""
    if finite == 0:
        return np.nan
    pos = max(finite - 1, 0) * (20.0 / 100.0)
    lo = int(np.floor(pos))
    hi = min(lo + 1, max(finite - 1, 0))
    kept = 0
    for k in range(profile.size):
        v = profile[k]
        if v != v or (kept == hi + 1 and v >= smallest[hi]):
            continue
        j = min(kept, hi)
        while j > 0 and smallest[j - 1] > v:
            smallest[j] = smallest[j - 1]
            j -= 1
        smallest[j] = v
        kept = min(kept + 1, hi + 1)
    frac = pos - lo
    return smallest[lo] * (1.0 - frac) + smallest[hi] * frac


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _crossing(profile: np.ndarray, level: float, half: int, direction: int) -> float:
    """Samples from the middle ``half`` to where the profile first falls below ``level``
    going ``direction`` (-1, 1), interpolated between the last sample above and the
    first below (NaN past the window's end, or at the middle itself)."""
    if not profile[half] >= level:
        return np.nan
    for j in range(1, half + 1):
        lo = profile[half + direction * j]
        if not lo >= level:   # NaN (outside the frame) counts as below
            hi = profile[half + direction * (j - 1)]
            frac = (hi - level) / (hi - lo) if hi > lo else 0.5
            frac = 0.5 if frac != frac else frac
            return j - 1 + min(max(frac, 0.0), 1.0)
    return np.nan
