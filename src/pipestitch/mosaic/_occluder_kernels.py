"""Compiled quantile and variance over a stack of frames (numba), for the occluder mask.

Why hand-written: numpy's quantile over a frame stack sorts with one partition per
pixel; this sorts a row of pixels' values at once (an odd-even transposition sort,
branch-free and contiguous over the row). numpy's variance over the frames makes a
temporary the size of the stack; this keeps one row's mean.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def quantile_over_frames(stack: np.ndarray, virtual: float,
                         median: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of an (n, H, W) float32 stack: its quantile and its median over frames.

    ``virtual`` is numpy's "linear" virtual index of the quantile, (n - 1)·q computed
    as ``numpy.quantile`` does; the interpolation between the two order statistics
    around it and the median (middle value, or the float32 mean of the two middle
    ones) follow ``numpy.quantile`` and ``numpy.median`` on float32 exactly. The
    median is computed only when asked (an empty array otherwise). Values must be
    finite.
    """
    n, height, width = stack.shape
    lo = min(max(int(np.floor(virtual)), 0), n - 1)
    hi = min(lo + 1, n - 1)
    gamma = virtual - np.floor(virtual)
    g, g1 = F32(gamma), F32(1 - gamma)
    quant = np.empty((height, width), np.float32)
    med = np.empty((height, width) if median else (0, 0), np.float32)
    buf = np.empty((n, width), np.float32)
    for i in range(height):
        for f in range(n):   # loops, not a slice assignment: less code to compile
            for j in range(width):
                buf[f, j] = stack[f, i, j]
        # Odd-even transposition sort of every pixel's n values at once: branch-free
        # and contiguous over the pixels of a row (an insertion sort per pixel is
        # several times slower on its mispredicted branches).
        for p in range(n):
            for k in range(p % 2, n - 1, 2):
                a, b = buf[k], buf[k + 1]
                for j in range(width):
                    x, y = a[j], b[j]
                    a[j] = min(x, y)
                    b[j] = max(x, y)
        for j in range(width):
            diff = buf[hi, j] - buf[lo, j]
            quant[i, j] = buf[hi, j] - diff * g1 if gamma >= 0.5 else buf[lo, j] + diff * g
            if median:
                mid = n // 2
                med[i, j] = buf[mid, j] if n % 2 else F32(buf[mid - 1, j] + buf[mid, j]) / F32(2)
    return quant, med


@numba.njit(cache=True, nogil=True, error_model="numpy")
def variance_over_frames(stack: np.ndarray, ddof: int) -> np.ndarray:
    """Per pixel of a C-ordered (n, H, W) float32 stack (n >= 1): its variance over the
    frames, as ``numpy.var(stack, axis=0, ddof=ddof)`` computes it for such a stack, to
    the bit (numpy sums pairwise where the frames' axis is the contiguous one): the
    frames summed in order in float32, the mean that sum over n in float64 rounded to
    float32, the squared float32 deviations summed in order, that sum over n - ddof in
    float64 rounded to float32. One pass a row instead of numpy's stack-sized temporary
    (11 frames of 1224 x 1024: ~0.2 s of the occluder mask's work beside the pose pass).
    """
    n, height, width = stack.shape
    out = np.empty((height, width), np.float32)
    mean = np.empty(width, np.float32)
    for i in range(height):
        for j in range(width):
            mean[j] = stack[0, i, j]
        for f in range(1, n):
            for j in range(width):
                mean[j] += stack[f, i, j]
        for j in range(width):
            mean[j] = F32(np.float64(mean[j]) / n)
            d = stack[0, i, j] - mean[j]
            out[i, j] = d * d
        for f in range(1, n):
            for j in range(width):
                d = stack[f, i, j] - mean[j]
                out[i, j] += d * d
        for j in range(width):
            out[i, j] = F32(np.float64(out[i, j]) / max(n - ddof, 0))
    return out
