"""Compiled inner loop of the strips' noise fields (numba): :func:`contrast_fields`.

Why hand-written: the fields are a dozen element-wise expressions and gradients on a
small grid (a few thousand nodes a strip); as numpy calls each one is a pass and a
temporary, and in a run the calls queue for the GIL behind the other worker (~5 ms a
strip measured, against ~1 ms alone). One loop over the grid releases the GIL.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)


@numba.njit(cache=True, nogil=True)
def _bspline(u: float) -> float:
    """The cubic B-spline at ``u`` (0 beyond 2): the phase-averaged correlation of
    linearly interpolated white noise between samples ``u`` pixels apart."""
    u = min(abs(u), 2.0)
    if u <= 1.0:
        return 2.0 / 3.0 - u * u * (1.0 - 0.5 * u)
    far = 2.0 - u
    return far * far * far / 6.0


@numba.njit(cache=True, nogil=True)
def _gradient_at(a: np.ndarray, i: int, k: int, axis: int) -> float:
    """``np.gradient(a, axis=axis)[i, k]`` (unit spacing, first-order edges)."""
    n = a.shape[axis]
    j = i if axis == 0 else k
    lo, hi, span = j - 1, j + 1, 2.0
    if j == 0:
        lo, span = 0, 1.0
    if j == n - 1:
        hi, span = n - 1, 1.0
    if axis == 0:
        return (a[hi, k] - a[lo, k]) / span
    return (a[i, hi] - a[i, lo]) / span


@numba.njit(cache=True, nogil=True)
def contrast_fields(map_x: np.ndarray, map_y: np.ndarray, local_mean: np.ndarray,
                    offset: float, slope: float, step: int) -> np.ndarray:
    """The fields of :func:`pipestitch.mosaic.noise.contrast_noise` on every ``step``-th
    node: (4, rows, columns) float32, E[g_n n] along the columns and the rows, then the
    gradient noise's variance along the columns and the rows (float64 inside)."""
    rows = (map_x.shape[0] + step - 1) // step
    cols = (map_x.shape[1] + step - 1) // step
    mx = np.empty((rows, cols))
    my = np.empty((rows, cols))
    relative = np.empty((rows, cols))
    for i in range(rows):
        for k in range(cols):
            mx[i, k] = map_x[i * step, k * step]
            my[i, k] = map_y[i * step, k * step]
            mean = max(np.float64(local_mean[i * step, k * step]), 1e-6)
            relative[i, k] = max(offset + slope * mean, 0.0) / (mean * mean)
    white = _bspline(0.0) * _bspline(0.0)   # a node's own share of the variance
    out = np.zeros((4, rows, cols), np.float32)
    lag1 = np.empty((rows, cols))
    for axis in range(2):
        if (rows, cols)[axis] < 2:
            continue
        field = 1 - axis   # the columns' fields first, as PatchNoise orders them
        for i in range(rows):
            for k in range(cols):
                dx = _gradient_at(mx, i, k, axis) / step
                dy = _gradient_at(my, i, k, axis) / step
                lag1[i, k] = relative[i, k] * _bspline(dx) * _bspline(dy)
                lag2 = relative[i, k] * _bspline(2.0 * dx) * _bspline(2.0 * dy)
                out[2 + field, i, k] = 0.5 * (relative[i, k] * white - lag2)
        for i in range(rows):
            for k in range(cols):
                out[field, i, k] = 0.5 * _gradient_at(lag1, i, k, axis) / step
    return out
