"""Pixels of the camera that never show the wall: mirror assembly, laser-holder arm, lens rim.

Without a mask file (probe.toml ``[probe] mask``), a dataset made by someone else may
have its arm anywhere and of any brightness, so occluders are found from the LED
frames themselves, by what makes them occluders: they are fixed in the image while the
wall moves past. A pixel is occluded when, over a sample of frames spread along the run,

* its brightness changes no more than the sensor's noise does (**static**: black,
  grey, bright or specular alike). The noise is measured on the frames themselves, as
  a function of the level: the local variance of each pixel's difference to its 3 x 3
  mean, taken at the quiet end (10th percentile) of each level's pixels. A wall pixel
  changes far more, even on a feature-poor wall, since the shading changes with the
  probe's offset; pixels saturated in most frames carry no evidence and are not taken;
* or it is dark relative to its neighbourhood (arm, mirror edge) or absolutely dark
  (outside the lens' image circle, the mirror's face) in nearly all frames (the 85th
  percentile over frames is dark). Dark wall features (holes,
stains, the black of a test chart) move between frames and so are dark in only some
of them: a median would not do, since a wall that is 40 % black is black in most of
11 frames at a quarter of its pixels. With fewer than 3 frames the mask also covers
that frame's dark wall features; the caller should sample frames spread along the run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from itertools import pairwise

import cv2
import numpy as np

from pipestitch.camera.frames import to_grey
from pipestitch.imaging import MAD_TO_SIGMA, median
from pipestitch.mosaic._occluder_kernels import quantile_over_frames, variance_over_frames

__all__ = ["FULL_SCALES", "defect_pixels", "full_scale", "noise_variance", "occluder_mask",
           "static_pixels"]

NEARLY_ALL = 0.85   # dark at this quantile over frames = dark in nearly all of them
# Static: temporal variance below this many times the sensor noise's, on a 5 x 5 mean
# (of a pure-noise pixel the ratio is ~1; over 11 frames its 99.9th percentile is ~3).
STATIC_RATIO = 4.0
# ... and the temporal variance of its 5 x 5 mean below this many times what the noise
# alone gives that mean (:func:`_mean_ratio`; leaves room for noise correlated over a few
# pixels, as in demosaiced frames, whose 5 x 5 mean keeps more of it).
MEAN_STATIC_RATIO = 8.0
MIN_STATIC_FRAMES = 5   # fewer frames cannot tell a static pixel from a slow wall
DEFECT_SIGMAS = 4.0     # a hot or dead pixel stands out of its 3 x 3 median by this much
DEFECT_QUANTA = 3.0     # ... and by at least this many steps of the frames' quantisation
# Frames of 1.5 times this many rows or more are area-averaged by a whole factor (the
# rows over this, rounded; a 2448 x 2048 frame by 2) to about this many rows first: the
# mask's finest structures (the static test's 5 x 5 mean, a static region of 1/100 of
# the frame) still span >= 5 px there, the margin dilation is applied at the frames' own
# pixels, and the mask costs a quarter. The windows named below are in those pixels.
MASK_ROWS = 1024


def _smooth(frame: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of width ``sigma`` (px), computed on a 4x smaller image.

    The neighbourhood is tens of pixels wide, so blurring the area-averaged image
    with sigma / 4 and enlarging it back differs from the full blur by far less than
    the 35 % contrast the mask looks for, at a twentieth of the cost.
    """
    h, w = frame.shape
    small = cv2.resize(frame, (max(1, w // 4), max(1, h // 4)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma / 4)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def occluder_mask(frames: Sequence[np.ndarray], *, relative: float = 0.35,
                  absolute: float = 0.08, margin_px: int | None = None,
                  workers: int = 1) -> np.ndarray:
    """Boolean mask of occluded pixels from LED frames of one run.

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        Frames of one size as stored (8- or 16-bit or float, grey or BGR), ideally 5-15
        spread along the run; each is made grey in [0, 1] by
        :func:`pipestitch.camera.frames.to_grey` where it enters the working stack, so
        the list holds no float copies.
    relative : float
        A pixel darker than this fraction of its neighbourhood (Gaussian of 1/40 of
        the image height) in nearly all frames is an occluder edge or body.
    absolute : float
        A pixel darker than this fraction of the frames' median level in nearly all
        frames is outside the image circle or on the mirror's face.
    margin_px : int, optional
        Dilation of the mask (default 1/200 of the image height, at least 2 px).
    workers : int
        Threads the frames are spread over (the result is the same).

    Returns
    -------
    numpy.ndarray
        bool (H, W), True where the wall is not seen.
    """
    if not frames:
        raise ValueError("occluder_mask: no frames")
    shape = np.shape(frames[0])[:2]
    if any(np.shape(f)[:2] != shape or np.ndim(f) not in (2, 3) for f in frames):
        raise ValueError("occluder_mask: expected frames of one size")
    factor = max(1, round(shape[0] / MASK_ROWS))
    work = (shape[0] // factor, shape[1] // factor)
    stack = np.empty((len(frames), *work), np.float32)
    ratios = np.empty_like(stack)
    sigma = max(3.0, work[0] / 40)

    def fill(k: int) -> None:   # each frame's rows of the stacks: no copy of the list
        if factor == 1:
            row = stack[k]
            grey = to_grey(frames[k], out=row)
            if grey is not row:
                row[...] = grey
        else:
            whole = to_grey(frames[k])[:work[0] * factor, :work[1] * factor]
            cv2.resize(whole, work[::-1], dst=stack[k], interpolation=cv2.INTER_AREA)
        np.divide(stack[k], np.maximum(_smooth(stack[k], sigma), 1e-6), out=ratios[k])

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        list(pool.map(fill, range(len(frames))))
    # numpy.quantile's "linear" virtual index, (n - 1)·q, in its arithmetic.
    virtual = (len(stack) - 1) * NEARLY_ALL
    ratio = quantile_over_frames(ratios, virtual, False)[0]
    level, typical = quantile_over_frames(stack, virtual, True)
    scale = float(median(typical[typical > 0])) if np.any(typical > 0) else 1.0
    mask = (ratio < relative) | (level < absolute * scale)
    if len(frames) >= MIN_STATIC_FRAMES:
        mask |= static_pixels(stack, typical)
    mask = mask.astype(np.uint8)
    if factor > 1:   # back to the frames' pixels (a border row or column: its neighbour's)
        mask = cv2.copyMakeBorder(
            cv2.resize(mask, (work[1] * factor, work[0] * factor),
                       interpolation=cv2.INTER_NEAREST),
            0, shape[0] - work[0] * factor, 0, shape[1] - work[1] * factor,
            cv2.BORDER_REPLICATE)
    margin = max(2, round(shape[0] / 200)) if margin_px is None else margin_px
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
    return cv2.dilate(mask, kernel).astype(bool)


def defect_pixels(frames: Sequence[np.ndarray], occluded: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Hot and dead pixels of the sensor, (rows, cols), from LED frames of one run.

    A pixel stands out of its 3 x 3 median by more than ``DEFECT_SIGMAS`` robust sigmas
    of that difference (1.4826 MAD over the pixels that see the wall: outside
    ``occluded`` and not black; at least ``DEFECT_QUANTA`` steps of the frames'
    quantisation), the same way in nearly all frames (``NEARLY_ALL``). The wall moves
    past a pixel; a pixel stuck bright or dark does not, and its fixed dot pulls the
    registration of consecutive strips towards no motion (a separate generator's 0.1 %
    hot pixels: refined tilts 1.3-4.5 deg off). The occluder mask does not take them
    (the static test's opening removes single pixels, and a saturated one is no static
    evidence), nor should it: a mask dotted over the frame leaves the registration's
    patches without a whole one. They are repaired instead
    (:func:`pipestitch.camera.frames.repair_pixels`). Fewer than ``MIN_STATIC_FRAMES``
    frames find none.
    """
    if len(frames) < MIN_STATIC_FRAMES:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    above = below = None
    for frame in frames:
        grey = to_grey(frame)
        resid = grey - cv2.medianBlur(grey, 3)
        seen = grey > 0
        if occluded is not None:
            seen &= ~occluded
        sample = np.abs(resid[::4, ::4][seen[::4, ::4]])
        spread = MAD_TO_SIGMA * float(median(sample)) if sample.size else 0.0
        quantum = 1.0 / np.iinfo(frame.dtype).max if frame.dtype.kind in "ui" else 1.0 / 255
        limit = max(DEFECT_SIGMAS * spread, DEFECT_QUANTA * quantum)
        if above is None:
            above, below = np.zeros(grey.shape, np.uint16), np.zeros(grey.shape, np.uint16)
        above += resid > limit
        below += resid < -limit
    need = math.ceil(NEARLY_ALL * len(frames))
    return np.nonzero((above >= need) | (below >= need))


def noise_variance(stack: np.ndarray, level: np.ndarray, *, bins: int = 16) -> np.ndarray:
    """The sensor's noise variance at each pixel's level, measured on the frames.

    Per frame (up to 4 of them), the variance of each pixel's difference to its 3 x 3
    mean over a 5 x 5 window, rescaled to the variance of one pixel (x 81/72, white
    noise); per level bin (``bins`` quantiles of ``level``), the 10th percentile over
    its pixels: the quiet parts of the image at that level (flat wall, the occluders
    themselves), where texture adds nothing. Interpolated to every pixel's level; NaN
    (unknown) where too few pixels measure it.
    """
    picks = np.asarray(stack, np.float32)[::max(1, len(stack) // 4)]
    # each pick's, written in place (no list, no stack); C order for OpenCV's dst
    residuals = np.empty(picks.shape, np.float32)
    for frame, out in zip(picks, residuals, strict=True):
        cv2.subtract(frame, cv2.blur(frame, (3, 3)), dst=out)
        cv2.multiply(out, out, dst=out)
        cv2.blur(out, (5, 5), dst=out)
    # the median over the picks (numpy.median's, from the compiled kernel: one pass)
    local = quantile_over_frames(residuals, 0.0, True)[1] * np.float32(81.0 / 72.0)
    valid = level > 0
    none = np.full(level.shape, np.nan, np.float32)   # no measure of the noise
    if np.count_nonzero(valid) < 100:
        return none
    edges = np.quantile(level[valid], np.linspace(0.0, 1.0, bins + 1))
    centres, noise = [], []
    for lo, hi in pairwise(edges):
        sel = valid & (level >= lo) & (level <= hi)
        if np.count_nonzero(sel) >= 100:
            centres.append(float(median(level[sel])))
            noise.append(float(np.percentile(local[sel], 10)))
    if len(centres) < 2:
        return none
    return np.interp(level, centres, noise).astype(np.float32)


# Full scales of integer frames scaled to [0, 1] by their file's range: 1 for 8-bit and
# 16-bit data, (2**bits - 1) / 65535 for 8-, 10-, 12- and 14-bit data in 16-bit files.
FULL_SCALES = tuple(sorted((2**bits - 1) / 65535 for bits in (8, 10, 12, 14))) + (1.0,)


def full_scale(top: float) -> float:
    """The sensor's full scale of frames whose brightest value is ``top``.

    The smallest of ``FULL_SCALES`` at or above ``top``: a 12-bit sensor's data in a
    16-bit file never exceed 4095 / 65535 of the file's range and clip there. An 8-bit
    frame's brightest value is at least 0.4 % above any of those full scales (64 / 255
    above 16383 / 65535 is the closest) or 1.2 % below it, so an 8-bit frame's full
    scale stays 1 unless it never reaches 1/4 of it. Float frames brighter than 1 clip
    at their maximum.
    """
    return next((f for f in FULL_SCALES if f >= top * (1 - 1e-6)), top)


def _mean_ratio(stack: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """The temporal variance of each pixel's 5 x 5 mean against what the noise alone gives
    it (a 25th of the noise variance, for white noise): where the noise is as strong as
    the wall's texture, a wall pixel varies little more than an occluder's (1.7-8 against
    1.2-1.7 times the noise, measured at 12.6 DN of noise on an 84 DN wall), but its mean
    over 5 x 5 varies with the texture, which is correlated over the window, and the
    noise's share falls 25-fold (wall 5-170, occluders 0.6-2.6)."""
    # Welford's running mean and sum of squares: three frame-sized arrays, not a second
    # stack (the mask is made beside the pose pass, where the run's memory peaks)
    mean = np.zeros(stack.shape[1:], np.float32)
    m2 = np.zeros_like(mean)
    blurred, delta = np.empty_like(mean), np.empty_like(mean)
    for k, frame in enumerate(stack, start=1):
        cv2.blur(frame, (5, 5), dst=blurred)
        np.subtract(blurred, mean, out=delta)
        mean += delta / np.float32(k)
        np.subtract(blurred, mean, out=blurred)
        m2 += delta * blurred
    return m2 / np.float32(max(len(stack) - 1, 1)) / np.maximum(noise / 25, 1e-12)


def static_pixels(stack: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Pixels whose value changes over the frames no more than the sensor noise.

    ``stack`` (n, H, W) float32 frames spread along the run, ``level`` their per-pixel
    median. A pixel is static when its temporal variance, averaged over 5 x 5, is
    below ``STATIC_RATIO`` times the noise variance at its level
    (:func:`noise_variance`; nothing is static where the noise could not be measured),
    its median is below the sensor's full scale (:func:`full_scale`: a clipped pixel does
    not vary either), and it belongs to a static region at least 1/100 of the image height
    across (an opening removes the odd wall pixel that happened to vary little).
    """
    noise = noise_variance(stack, level)
    if not np.any(np.isfinite(noise)):
        return np.zeros(level.shape, bool)
    # numpy.var(stack, axis=0, ddof=1), to the bit
    temporal = variance_over_frames(np.ascontiguousarray(stack, np.float32), 1)
    ratio = cv2.blur(temporal / np.maximum(noise, 1e-12), (5, 5))
    saturated = level >= 0.999 * full_scale(float(stack.max()))
    static = ((ratio < STATIC_RATIO) & (_mean_ratio(stack, noise) < MEAN_STATIC_RATIO)
              & np.isfinite(noise) & ~saturated & (level > 0))
    size = max(3, round(stack.shape[1] / 100)) | 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.morphologyEx(static.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
