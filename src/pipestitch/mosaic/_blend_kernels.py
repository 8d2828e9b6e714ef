"""Compiled inner loops of blending (numba): shaded albedo, feathered weights, the
exposure gain's node ratios and the accumulation of a strip into the canvas.

Why hand-written: each is a fused pass over a whole strip that numpy would run as
several temporary arrays.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

F32 = np.float32
# the gain's node thresholds, as float32 (numpy compares float32 arrays with a Python
# float in float32): the strip's weight, the canvas' weight, the strip's albedo
GAIN_WEIGHT_MIN = F32(0.2)
GAIN_HAVE_MIN = F32(0.5)
GAIN_ALBEDO_MIN = F32(1e-6)


@numba.njit(cache=True, nogil=True)
def shaded_albedo(values: np.ndarray, shading: np.ndarray,
                  weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values / max(shading, 1e-6)`` (float64 arithmetic) stored as float32, 0 where
    there is no data, and the validity (uint8: the albedo is finite and ``weight`` > 0).
    """
    n_rows, n_cols = values.shape
    albedo = np.empty((n_rows, n_cols), np.float32)
    valid = np.empty((n_rows, n_cols), np.uint8)
    for i in range(n_rows):
        for j in range(n_cols):
            v = values[i, j] / max(np.float64(shading[i, j]), 1e-6)
            if np.isfinite(v) and weight[i, j] > 0:
                albedo[i, j] = F32(v)
                valid[i, j] = 1
            else:
                albedo[i, j] = F32(0)
                valid[i, j] = 0
    return albedo, valid


@numba.njit(cache=True, nogil=True)
def feathered_weight(weight: np.ndarray, distance: np.ndarray, valid: np.ndarray,
                     feather_px: int) -> np.ndarray:
    """``weight · feather`` (float32) where ``valid``, else 0; the feather is
    ``min(max(distance / feather_px, 0), 1)`` in float32, as ``numpy.clip`` of the
    float32 quotient gives it. ``distance`` is that of the strip wrapped by
    ``feather_px`` rows and padded by a column each side: node (i, j) is at
    (i + ``feather_px``, j + 1).
    """
    out = np.empty(weight.shape, np.float32)
    step = F32(feather_px)
    for i in range(weight.shape[0]):
        for j in range(weight.shape[1]):
            feather = min(max(distance[i + feather_px, j + 1] / step, F32(0)), F32(1))
            out[i, j] = weight[i, j] * feather if valid[i, j] else F32(0)
    return out


@numba.njit(cache=True, nogil=True)
def accumulate_strip(total: np.ndarray, weights: np.ndarray, col0: int, albedo: np.ndarray,
                     weight: np.ndarray, gain: float) -> None:
    """``total[:, col0:] += albedo · gain · weight`` and ``weights[:, col0:] += weight``
    in place over the strip's columns (float32 sums of float64 products)."""
    for i in range(albedo.shape[0]):
        for j in range(albedo.shape[1]):
            w = weight[i, j]
            if w != 0:
                total[i, col0 + j] = F32(np.float64(total[i, col0 + j])
                                         + np.float64(albedo[i, j]) * gain * np.float64(w))
                weights[i, col0 + j] += w


@numba.njit(cache=True, nogil=True, error_model="numpy")
def gain_ratios(total: np.ndarray, weights: np.ndarray, col0: int, albedo: np.ndarray,
                weight: np.ndarray, stride: int, out: np.ndarray) -> int:
    """The exposure gain's node ratios of a strip at window column ``col0``: over every
    ``stride``-th row and column of the strip, where its ``weight`` > 0.2, the canvas'
    ``weights`` > 0.5 and its ``albedo`` > 1e-6, ``total / (weights · albedo)`` (float32
    comparisons and arithmetic, as numpy does them on these float32 arrays), written to
    ``out`` (as long as the nodes read) in row order; returns how many.

    Every node's ratio is written and the count moves on only where the node is kept:
    no branch to mispredict where kept and dropped nodes alternate (half the time of
    a branch on a textured overlap); a dropped node's ratio (inf or NaN where a weight
    is 0) is overwritten or left beyond the count.
    """
    n = 0
    for i in range(0, albedo.shape[0], stride):
        for j in range(0, albedo.shape[1], stride):
            have = weights[i, col0 + j]
            mine = albedo[i, j]
            out[n] = total[i, col0 + j] / (have * mine)
            kept = weight[i, j] > GAIN_WEIGHT_MIN
            n += kept & (have > GAIN_HAVE_MIN) & (mine > GAIN_ALBEDO_MIN)
    return n
