"""Photometric evidence on the mirror ambiguity from consecutive LED frames.

Unwrapped with the true poses, two LED frames a few millimetres apart show the same
wall up to a global shift (the probe's advance and roll); unwrapped with a mirror
pose the strip is warped non-rigidly (about 0.17 / 0.34 / 0.7 / 1.5 mm RMS at
0.5 / 1 / 2 / 4° of tilt in a 65 mm pipe), so no shift makes them agree. For each of
the four combinations of the two frames' hypotheses we unwrap a window of wall
20-60 mm ahead (scaled with the radius) and ask how well a single global shift
explains the pair: the peak of their phase correlation (``cv2.phaseCorrelate``,
circular in theta) on the local contrast. The costs are likelihood ratios with a
deliberately small effective sample size (residuals are correlated over blocks of
pixels), capped so one pair of frames cannot outvote the rest of the run.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, WallGrid
from pipestitch.imaging import gaussian_blur, nanmedian
from pipestitch.mosaic._photometric_kernels import ccs_modulus, contrast_and_dark, masked_contrast
from pipestitch.mosaic._unwrap_kernels import fill_invalid
from pipestitch.mosaic.unwrap import unwrap
from pipestitch.pose.fit import PoseFit

__all__ = ["StripPair", "contrast_strip", "contrast_strips", "pair_costs", "strip_misfit"]

STRIP_ROWS = 584    # nodes around the pipe in a comparison strip
BLOCK_PX = 8        # residuals are treated as independent per 8 x 8 block
MAX_COST = 30.0     # cap on one pair's evidence (negative log-likelihood units)
# Frames further apart than this share of the comparison window (by the odometer) are
# not compared; nor are frames whose best-agreeing combination peaks below MIN_PEAK
# (registration trusts no peak below 0.04): they show too little common wall for their
# agreement to say anything (frames 5 mm apart: 0.81; 30 mm apart in a 39 mm window:
# <= 0.02, where without the floor the comparison chose wrong mirrors with margins of
# 13-24 on 25-30 mm steps).
MAX_SHIFT_SHARE = 0.5
MIN_PEAK = 0.05


@dataclass(frozen=True)
class _Comparable:
    """What a comparison reads of a strip: where it has values (bool, the strip's
    shape: two strips' common nodes are counted in a few microseconds, against ~50 for
    a product of float masks), how many nodes that is, and the spectrum
    ``cv2.phaseCorrelate`` takes of it (:func:`_spectrum`)."""

    valid: np.ndarray
    count: int
    spectrum: np.ndarray


def _comparable(strip: np.ndarray) -> _Comparable:
    filled, valid = fill_invalid(np.ascontiguousarray(strip, np.float32))
    mask = valid.astype(bool)
    return _Comparable(mask, int(np.count_nonzero(mask)), _spectrum(filled))


def _spectrum(filled: np.ndarray) -> np.ndarray:
    """The DFT ``cv2.phaseCorrelate`` takes of a strip (its values with 0 where it has
    none): tapered by :func:`_z_window`, zero-padded to OpenCV's optimal DFT size,
    packed (CCS) float32. Each strip is compared four times; its spectrum is taken once.
    """
    rows, cols = filled.shape
    tapered = np.multiply(filled, _z_window(filled.shape))
    padded = cv2.copyMakeBorder(tapered, 0, cv2.getOptimalDFTSize(rows) - rows, 0,
                                cv2.getOptimalDFTSize(cols) - cols, cv2.BORDER_CONSTANT, value=0)
    return cv2.dft(padded, flags=cv2.DFT_REAL_OUTPUT)


def _peak_response(spectrum_b: np.ndarray, spectrum_a: np.ndarray) -> float:
    """``cv2.phaseCorrelate(b, a, window)``'s response from the strips' :func:`_spectrum`:
    its steps after the two DFTs, to the bit (the cross-power spectrum divided by its
    modulus, the inverse DFT shifted to centre its zero, and the sum over a 5 x 5
    window around the first maximum, cut at the edges, over the number of cells)."""
    product = cv2.mulSpectrums(spectrum_b, spectrum_a, 0, conjB=True)
    unit = cv2.divSpectrums(product, ccs_modulus(product), 0, conjB=False)
    surface = np.fft.fftshift(cv2.idft(unit))
    _, _, _, (col, row) = cv2.minMaxLoc(surface)
    total = 0.0
    # row by row in float64, as OpenCV sums them
    for value in surface[max(row - 2, 0):row + 3, max(col - 2, 0):col + 3].ravel().tolist():
        total += value
    return total / surface.size


@dataclass(frozen=True)
class StripPair:
    """Local-contrast strips of one frame for its two hypotheses (NaN = no data).

    Each strip is compared four times (two hypotheses of the frame before and of the
    frame after): what the comparisons read of it, its spectrum included, is prepared
    once, with the strips (on the pose pass's workers).
    """

    strips: tuple[np.ndarray, ...]
    comparable: tuple[_Comparable, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "comparable", tuple(_comparable(s) for s in self.strips))


def _contrast(strip: np.ndarray) -> np.ndarray:
    """Local contrast (value / local mean - 1); dark, masked or occluded nodes are NaN.

    ``strip``: float32 (:func:`~pipestitch.mosaic.unwrap.unwrap`'s). The arithmetic is
    float32, in compiled passes around OpenCV's blurs and dilation
    (:mod:`pipestitch.mosaic._photometric_kernels`).
    """
    strip = np.ascontiguousarray(strip, np.float32)
    filled, valid = fill_invalid(strip)
    weight = gaussian_blur(valid, 6.0)
    med = nanmedian(strip) if valid.any() else np.float32(0)
    # Very dark nodes are the laser holder arm, the mirror assembly or holes: they do
    # not move with the wall, so they are masked (with a margin) rather than compared.
    contrast, dark = contrast_and_dark(filled, gaussian_blur(filled, 6.0), weight, valid,
                                       np.float32(0.25) * med)
    return masked_contrast(contrast, cv2.dilate(dark, np.ones((5, 5), np.uint8)), weight)


def contrast_strips(led: np.ndarray, camera: CameraModel, fit: PoseFit,
                    mm_per_px: float | None = None) -> StripPair:
    """Unwrap ``led`` (grey float) with each hypothesis of ``fit`` over the comparison window.

    The window runs from 0.6 to 1.8 radii ahead; its pitch (default) is the
    circumference over ``STRIP_ROWS``, so every pipe's strips have the same nodes
    whatever its size (0.35 mm in a 65 mm pipe), and so does the cost of comparing them.

    The maps are projected exactly at every 4th node and interpolated between (ten
    times faster; ~0.03 px from the exact maps at most, far below what a mirror pose
    warps the strip by).
    """
    return StripPair(tuple(contrast_strip(led, camera, h.pose, PipeSection(h.radius_mm),
                                          mm_per_px) for h in fit.hypotheses))


def contrast_strip(led: np.ndarray, camera: CameraModel, pose: Pose, section: PipeSection,
                   mm_per_px: float | None = None) -> np.ndarray:
    """The local contrast of ``led`` (grey float) unwrapped with one pose and section over
    :func:`contrast_strips`' comparison window (NaN = no data)."""
    r = section.mean_radius_mm
    grid = WallGrid.window(r, mm_per_px or 2 * np.pi * r / STRIP_ROWS, 0.6 * r, 1.8 * r)
    return _contrast(unwrap(led, camera, pose, section, grid, step=4))


def strip_misfit(a: np.ndarray, b: np.ndarray) -> float:
    """How badly one global shift explains strip ``b`` against ``a`` (two
    :func:`contrast_strip` of consecutive frames): 1 - their phase-correlation peak,
    NaN without enough common data."""
    return _misfit(a, b)[0]


def _misfit(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """How badly one global shift explains b against a: 1 - phase-correlation peak.

    The normalised peak of the cross-power spectrum measures exactly "the same wall up
    to a translation", whatever the texture's contrast. A plain squared difference
    (or NCC) after the shift is not used: on a feature-poor wall it is mostly sensor
    noise, the same for every combination, and its random differences read as
    evidence (measured: wrong decisions on brushed aluminium at 2-5° of tilt).

    Returns
    -------
    misfit : float
        1 - peak response, in [0, 1]; NaN without enough data.
    count : int
        Number of valid nodes the strips share.
    """
    return _compare(_comparable(a), _comparable(b))


def _compare(a: _Comparable, b: _Comparable) -> tuple[float, int]:
    """:func:`_misfit` of two prepared strips."""
    if a.count < 100 or b.count < 100 or a.valid.shape != b.valid.shape:
        return np.nan, 0
    response = _peak_response(b.spectrum, a.spectrum)
    return 1.0 - response, int(np.count_nonzero(a.valid & b.valid))


@functools.lru_cache(maxsize=8)
def _z_window(shape: tuple[int, int]) -> np.ndarray:
    """A Hanning taper along z only (the strips are circular in theta), float32;
    read-only, as every comparison of strips of this shape shares it."""
    win = cv2.createHanningWindow((shape[1], shape[0]), cv2.CV_32F)
    win = np.tile(win[shape[0] // 2:shape[0] // 2 + 1, :], (shape[0], 1))
    win.flags.writeable = False
    return win


def pair_costs(first: StripPair, second: StripPair) -> np.ndarray:
    """2 x 2 costs of (hypothesis i of the first frame, j of the second).

    0 for the best-agreeing combination; others cost N_eff/2 · log(U_ij / U_min) with
    U = 1 - phase-correlation peak (see :func:`_misfit`) and N_eff the overlap in 8 x 8
    blocks, capped at ``MAX_COST``. All zero when the frames do not overlap.
    """
    misfit = np.full((2, 2), np.nan)
    count = np.zeros((2, 2))
    for i, a in enumerate(first.comparable):
        for j, b in enumerate(second.comparable):
            misfit[i, j], count[i, j] = _compare(a, b)
    if not np.all(np.isfinite(misfit)) or np.min(misfit) <= 0 or np.min(misfit) > 1 - MIN_PEAK:
        return np.zeros((2, 2))
    n_eff = np.min(count) / BLOCK_PX**2
    return np.minimum(0.5 * n_eff * np.log(misfit / np.min(misfit)), MAX_COST)
