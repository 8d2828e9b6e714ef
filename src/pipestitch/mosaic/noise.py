"""Sensor noise of the LED frames, and what it does to the patch shifts of a feature-poor wall.

A strip is the frame resampled (bilinear) onto the wall grid, so neighbouring strip
nodes that draw on the same frame pixels share their noise: where the wall is seen at
less than a pixel per node the noise of the local contrast is correlated between
neighbours, more so towards the far end of the strip. A Lucas-Kanade step takes the
template's gradient g (central differences) and the residual ``moved - template``;
the template's noise n is then in both, and E[g_n(p) n(p)] = (C(p, p+e) - C(p-e, p)) / 2
(C: the noise covariance of neighbouring nodes along axis e) is not zero where C
changes along the strip. That term biases every patch shift the same way; on a wall
whose texture is as weak as the noise (brushed aluminium at 1224 x 1024) it is the
0.07 % axial scale shortfall of the mosaic (docs/benchmarks.md, "The patch shifts
against exact ground truth"). The noise also inflates the Hessian by Var(g_n), which
shortens every step. Both are known from the frame's noise and the unwrap's geometry,
so they are subtracted (:func:`patch_table`, :func:`patch_noise`, used by
:func:`pipestitch.mosaic.register.phase_shift`); on a textured wall they are a small
part of the gradients' own sums and change nothing.

* :func:`estimate_noise`: the frames' noise variance against signal level (shot and
  read noise, the quantisation), from the frames themselves: in 16 x 16 blocks, the
  variance of a high-pass that cancels any linear shading, and per signal level a low
  quantile of the blocks (the flattest blocks of the wall are noise alone), corrected
  by the quantile of a chi-square with the blocks' effective degrees of freedom.
* :func:`contrast_noise`: per strip, on every ``step``-th node, D = E[g_n n] and
  Var(g_n) / 2 of the local contrast along each axis, phase-averaged: bilinear
  interpolation of white noise correlates two samples u pixels apart by R(u) = the
  cubic B-spline (the linear kernel's autocorrelation), per axis of the frame.

Written by hand: neither OpenCV nor scikit-image models the noise of a remapped image.
The fields' loop is compiled (:mod:`pipestitch.mosaic._noise_kernels`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.special import gammaincinv

from pipestitch.mosaic import _noise_kernels as _k

__all__ = ["ContrastNoise", "NoiseModel", "PatchNoise", "contrast_noise", "estimate_noise",
           "patch_noise", "patch_noise_sums", "patch_table"]

# A second difference in both directions: zero on any linear shading (LED fall-off,
# vignetting), sum of squares 36.
SECOND_DIFFERENCE = np.array([1.0, -2.0, 1.0])
HIGH_PASS = np.outer(SECOND_DIFFERENCE, SECOND_DIFFERENCE).astype(np.float32)
BLOCK_PX = 16          # blocks of the frame whose high-pass variance is one sample
BLOCK_QUANTILE = 0.1   # of the blocks at one signal level: the flattest are noise alone
LEVELS = 12            # signal levels the model is fitted over
MIN_BLOCKS = 50        # blocks a level needs
CLIP_MARGIN = 0.01     # blocks with a pixel this close to 0 or full scale are left out
NODE_STEP = 4          # the noise fields are smooth: every 4th strip node


def _quantile_factor() -> float:
    """E-normalised ``BLOCK_QUANTILE`` of a block's high-pass variance for white noise:
    a chi-square with the block's effective degrees of freedom (the high-pass correlates
    neighbouring pixels: dof = pixels / sum of the squared autocorrelation). The filter is
    separable, so is its autocorrelation; the chi-square quantile is 2 P^-1(dof / 2, q)
    (the regularised incomplete gamma function's inverse: scipy.stats is not loaded for
    one number, it adds half a second and 30 MB to every run's start)."""
    line = np.correlate(SECOND_DIFFERENCE, SECOND_DIFFERENCE, "full")
    rho = np.outer(line, line) / float((HIGH_PASS ** 2).sum())
    dof = BLOCK_PX ** 2 / float((rho ** 2).sum())
    return float(2.0 * gammaincinv(dof / 2.0, BLOCK_QUANTILE) / dof)


QUANTILE_FACTOR = _quantile_factor()


@dataclass(frozen=True)
class NoiseModel:
    """Noise variance of a frame pixel (grey, full scale 1) at signal level s:
    ``offset + slope * s`` (read noise and quantisation; shot noise)."""

    offset: float
    slope: float

    def variance(self, level: np.ndarray) -> np.ndarray:
        """Variance at each signal ``level`` (never below 0)."""
        return np.maximum(self.offset + self.slope * np.asarray(level, np.float64), 0.0)


def estimate_noise(frames: Iterable[np.ndarray]) -> NoiseModel | None:
    """The frames' noise model (grey float frames of full scale 1), or None when they
    have too few unclipped blocks to fit one.

    Parameters
    ----------
    frames : iterable of numpy.ndarray
        Grey float32 frames (:func:`pipestitch.camera.frames.to_grey`), each used once
        (a generator holds one at a time).

    Returns
    -------
    NoiseModel or None
    """
    levels, variances = [], []
    for frame in frames:
        level, variance = _block_stats(np.asarray(frame, np.float32))
        levels.append(level)
        variances.append(variance)
    if not levels:
        return None
    level, variance = np.concatenate(levels), np.concatenate(variances)
    if level.size < MIN_BLOCKS * 2:
        return None
    edges = np.unique(np.quantile(level, np.linspace(0.0, 1.0, LEVELS + 1)))
    x, y = [], []
    for lo, hi in itertools.pairwise(edges):
        sel = (level >= lo) & (level < hi)
        if np.count_nonzero(sel) >= MIN_BLOCKS:
            x.append(float(np.median(level[sel])))
            y.append(float(np.quantile(variance[sel], BLOCK_QUANTILE)) / QUANTILE_FACTOR)
    if len(x) < 2:
        return None
    slope, offset = np.polyfit(x, y, 1)
    if slope < 0:   # no shot noise to see (e.g. compressed frames): a constant
        slope, offset = 0.0, float(np.median(y))
    return NoiseModel(float(max(offset, 0.0)), float(slope))


def _block_stats(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean level and high-pass noise variance of the frame's unclipped blocks."""
    high = cv2.filter2D(frame, cv2.CV_32F, HIGH_PASS, borderType=cv2.BORDER_REFLECT)
    rows, cols = (frame.shape[0] // BLOCK_PX) * BLOCK_PX, (frame.shape[1] // BLOCK_PX) * BLOCK_PX
    shape = (rows // BLOCK_PX, BLOCK_PX, cols // BLOCK_PX, BLOCK_PX)
    if rows < 3 * BLOCK_PX or cols < 3 * BLOCK_PX:
        return np.empty(0), np.empty(0)
    blocks = frame[:rows, :cols].reshape(shape)
    power = (high[:rows, :cols].astype(np.float64) ** 2).reshape(shape).mean(axis=(1, 3))
    low, high_level = blocks.min(axis=(1, 3)), blocks.max(axis=(1, 3))
    keep = (low > CLIP_MARGIN) & (high_level < 1.0 - CLIP_MARGIN)
    keep[0, :] = keep[-1, :] = keep[:, 0] = keep[:, -1] = False
    return (blocks.mean(axis=(1, 3), dtype=np.float64)[keep],
            power[keep] / float((HIGH_PASS ** 2).sum()))


@dataclass(frozen=True)
class ContrastNoise:
    """A strip's contrast-noise fields on every ``step``-th node.

    ``fields`` (4, node rows, node columns), float32: E[g_n n] of the central-difference
    gradient along the columns (z) and along the rows (theta), then the gradient noise's
    variance along the columns and along the rows (the order of :class:`PatchNoise`).
    """

    step: int
    fields: np.ndarray
    _tables: dict[bytes, np.ndarray] = field(default_factory=dict, init=False, repr=False,
                                             compare=False)

    def patch_table(self, window: np.ndarray) -> np.ndarray:
        """:func:`patch_table` of these fields under ``window``, computed once per
        window (a strip is the template of each of its links to later frames)."""
        key = np.ascontiguousarray(window).tobytes() + repr(window.shape).encode()
        table = self._tables.get(key)
        if table is None:
            table = self._tables[key] = patch_table(self, window)
        return table


def contrast_noise(map_x: np.ndarray, map_y: np.ndarray, local_mean: np.ndarray,
                   model: NoiseModel, step: int = NODE_STEP) -> ContrastNoise:
    """The noise fields of a strip's local contrast (value / local mean - 1).

    Parameters
    ----------
    map_x, map_y : numpy.ndarray
        The strip's remap maps (frame column and row of each node).
    local_mean : numpy.ndarray
        The strip's local mean (the contrast's divisor).
    model : NoiseModel
        The frames' noise.
    step : int
        Fields on every ``step``-th node (they are smooth).

    Returns
    -------
    ContrastNoise
    """
    fields = _k.contrast_fields(np.ascontiguousarray(map_x, np.float32),
                                np.ascontiguousarray(map_y, np.float32),
                                np.ascontiguousarray(local_mean, np.float32),
                                float(model.offset), float(model.slope), int(step))
    return ContrastNoise(step, fields)


@dataclass(frozen=True)
class PatchNoise:
    """What the template's noise adds to a Lucas-Kanade patch's sums (window-weighted):
    ``d_x``, ``d_y`` to the residual moments, ``h_x``, ``h_y`` to the Hessian's diagonal
    (x: columns, y: rows)."""

    d_x: float
    d_y: float
    h_x: float
    h_y: float


def patch_table(noise: ContrastNoise, window: np.ndarray) -> np.ndarray:
    """Every patch's noise sums at once: (4, node rows, node columns), at [:, i, k] the
    :class:`PatchNoise` of the patch under ``window`` whose first row and column are
    those of node (i, k) (rows wrap; one separable correlation per field, so that a
    patch costs a look-up). ``window`` must be separable (an outer product, as a
    Hanning window is)."""
    step, fields = noise.step, noise.fields
    half = step // 2
    weight = window[half::step, half::step].astype(np.float64) * (step * step)
    u, s, vt = np.linalg.svd(weight)
    if s.size > 1 and s[1] > 1e-6 * s[0]:
        raise ValueError("patch_table: the window is not separable")
    k_rows, k_cols = u[:, 0] * np.sqrt(s[0]), vt[0] * np.sqrt(s[0])
    wrapped = np.concatenate([fields, fields[:, :weight.shape[0] - 1]], axis=1)
    table = [cv2.sepFilter2D(f, -1, k_cols.astype(np.float32), k_rows.astype(np.float32),
                             anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)
             for f in wrapped]
    return np.stack(table)[:, :fields.shape[1]]


def patch_noise(table: np.ndarray, step: int, row0: int, col0: int) -> PatchNoise:
    """The noise sums of the template patch whose first strip row is ``row0`` (wrapping)
    and first column ``col0``, from :func:`patch_table` (fields every ``step`` nodes)."""
    sums = patch_noise_sums(table, step, np.array([row0]), np.array([col0]))[0]
    return PatchNoise(*(float(v) for v in sums))


def patch_noise_sums(table: np.ndarray, step: int, rows0: np.ndarray,
                     cols0: np.ndarray) -> np.ndarray:
    """:func:`patch_noise` of many patches (first rows ``rows0``, first columns
    ``cols0``): (n, 4) float64, columns in :class:`PatchNoise`'s order."""
    half = step // 2
    i = ((np.asarray(rows0, np.int64) + half) // step) % table.shape[1]
    k = np.minimum((np.asarray(cols0, np.int64) + half) // step, table.shape[2] - 1)
    return np.ascontiguousarray(table[:, i, k].T, np.float64)
