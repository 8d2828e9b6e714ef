"""Pixels of the camera that never show the wall: mirror assembly, laser-holder arm, lens rim.

probe.toml does not describe the probe's occluders, and a dataset made by someone
else may have its arm anywhere, so they are found from the LED frames themselves:
they are fixed in the image while the wall moves past. A pixel is occluded when it
is dark relative to its neighbourhood (arm, mirror edge) or absolutely dark (outside
the lens' image circle, the mirror's face) in nearly all frames of a sample spread
over the run (the 85th percentile over frames is dark). Dark wall features (holes,
stains, the black of a test chart) move between frames and so are dark in only some
of them: a median would not do, since a wall that is 40 % black is black in most of
11 frames at a quarter of its pixels. With fewer than 3 frames the mask also covers
that frame's dark wall features; the caller should sample frames spread along the run.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from pipestitch.mosaic._occluder_kernels import quantile_over_frames

__all__ = ["occluder_mask"]

NEARLY_ALL = 0.85   # dark at this quantile over frames = dark in nearly all of them


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
    """Boolean mask of occluded pixels from grey LED frames of one run.

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        Grey float frames (same shape), ideally 5-15 spread along the run.
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
    shape = np.shape(frames[0])
    if any(np.shape(f) != shape for f in frames) or len(shape) != 2:
        raise ValueError("occluder_mask: expected grey frames of one size")
    stack = np.empty((len(frames), *shape), np.float32)
    ratios = np.empty_like(stack)
    height = shape[0]
    sigma = max(3.0, height / 40)

    def fill(k: int) -> None:   # each frame's rows of the stacks: no copy of the list
        stack[k] = frames[k]
        np.divide(stack[k], np.maximum(_smooth(stack[k], sigma), 1e-6), out=ratios[k])

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        list(pool.map(fill, range(len(frames))))
    # numpy.quantile's "linear" virtual index (n·q + (1 - q) - 1), in its arithmetic.
    virtual = len(stack) * NEARLY_ALL + (1 - NEARLY_ALL) - 1
    ratio = quantile_over_frames(ratios, virtual, False)[0]
    level, typical = quantile_over_frames(stack, virtual, True)
    scale = float(np.median(typical[typical > 0])) if np.any(typical > 0) else 1.0
    mask = (ratio < relative) | (level < absolute * scale)
    margin = max(2, round(height / 200)) if margin_px is None else margin_px
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
