"""Camera frames as grey values: the one conversion every stage uses.

A frame arrives as the camera (or the simulator, or an image file) gives it: 8- or
16-bit or float, grey or BGR(A). :func:`to_grey` turns any of them into grey
float32, integer ranges scaled to [0, 1]; stages that need something else (OpenCV's
board finder wants 8 bits, a photo texture wants values clipped to [0, 1]) start
from it.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipestitch._runtime import scratch
from pipestitch.imaging import median, scaled_float32

__all__ = ["blank_frame", "mean_level", "repair_pixels", "to_grey"]


def to_grey(img: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
    """An 8/16-bit or float, grey or BGR(A) frame as grey float32 (integer ranges to [0, 1]).

    Parameters
    ----------
    img : numpy.ndarray, shape (H, W) or (H, W, C)
        The frame. Integer frames are scaled by ``1 / iinfo(dtype).max``; float
        frames keep their values, with NaN and infinities set to 0. Three or more
        channels are BGR(A) and converted with ``cv2.COLOR_BGR2GRAY`` (in float32,
        after the cast); fewer than three: the first channel is taken.
    out : numpy.ndarray, optional
        A float32 (H, W) array that a grey integer frame or a colour frame is written
        into (see :mod:`pipestitch._runtime.scratch`); other frames get a new array.

    Returns
    -------
    numpy.ndarray, shape (H, W), float32
        The grey frame; ``out`` itself when it was used. For a grey integer frame
        exactly ``img.astype(float32) * float32(1 / iinfo(dtype).max)``.
    """
    arr = np.asarray(img)
    integer = arr.dtype.kind in "ui"
    scale = 1.0 / np.iinfo(arr.dtype).max if integer else 1.0
    if integer and arr.ndim == 2:
        # One pass (cast and scale, the same float32 arithmetic): a frame is read
        # once per pass of the mosaic.
        return scaled_float32(arr, scale, out=out)
    if arr.ndim == 3 and arr.shape[2] >= 3:
        arr = _bgr_to_grey(arr, out)
    else:
        arr = arr.astype(np.float32)
        arr = arr[..., 0] if arr.ndim == 3 else arr
    arr = np.multiply(arr, np.float32(scale), out=arr if arr.flags.writeable else None)
    # Only a float frame can hold NaN or infinities.
    return arr if integer else np.nan_to_num(arr, copy=False, nan=0.0, posinf=0.0, neginf=0.0)


COLOUR_ROWS = 32   # rows of a colour frame cast at a time: their float32 copy (~0.5 MB
                   # at 1224 px) stays in a core's cache between the cast and OpenCV


def _bgr_to_grey(arr: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    """``cv2.cvtColor(arr[..., :3].astype(float32), COLOR_BGR2GRAY)`` (into ``out`` when
    it is a float32 array of the frame's size), a block of rows at a time: the whole
    frame's float32 copy (15 MB at 1224 x 1024) went to memory and back, 3.6 ms a
    frame in a run. The same values: the conversion is pixel by pixel."""
    rows, cols = arr.shape[:2]
    if (out is None or out.shape != (rows, cols) or out.dtype != np.float32
            or not out.flags.c_contiguous):
        out = np.empty((rows, cols), np.float32)
    block = scratch.buffer("grey.colour", (min(COLOUR_ROWS, rows), cols, 3), np.float32)
    for first in range(0, rows, COLOUR_ROWS):
        last = min(first + COLOUR_ROWS, rows)
        part = block[:last - first]
        np.copyto(part, arr[first:last, :, :3], casting="unsafe")
        cv2.cvtColor(part, cv2.COLOR_BGR2GRAY, dst=out[first:last])
    return out


BLANK_SAMPLE = 4        # every 4th row and column is looked at (a 1224-px frame: 78k pixels)
BLANK_TAIL = 0.001      # the share of samples either end of the range may hold (hot pixels)
BLANK_STEPS = 2         # a range of at most 2 quantisation steps holds no picture


def blank_frame(img: np.ndarray) -> str:
    """Why a frame shows no picture at all, or "" when it shows one.

    A frame shows nothing when, apart from a thousandth of its pixels at either end
    (hot or dead pixels, a glint), all of it lies within two quantisation steps of one
    value: a black frame (LEDs off, a dropped exposure), a white one (saturated) or a
    flat grey one (a frame the recorder filled in). The step is the file's own: one
    count of an integer frame, 1/255 of full scale for a float one. Looked at on every
    4th row and column, so it costs far less than a decode.

    Parameters
    ----------
    img : numpy.ndarray, shape (H, W) or (H, W, C)
        The frame as decoded (any dtype, grey or colour; NaN counts as no picture).

    Returns
    -------
    str
        "" or the reason, e.g. ``"every pixel is 0 (a black frame)"``.
    """
    arr = np.asarray(img)
    if _clearly_a_picture(arr):
        return ""
    sample = arr[::BLANK_SAMPLE, ::BLANK_SAMPLE].reshape(-1)
    if sample.dtype.kind == "f":
        finite = sample[np.isfinite(sample)]
        if finite.size < (1 - BLANK_TAIL) * sample.size:
            return "it holds no finite values"
        sample, step, top = finite, 1.0 / 255, 1.0
    else:
        step, top = 1.0, float(np.iinfo(sample.dtype).max)
    if sample.size == 0:
        return "it holds no pixels"
    k = int(BLANK_TAIL * sample.size)
    ends = np.partition(sample, (k, sample.size - 1 - k))   # O(n), unlike a sort
    if float(ends[sample.size - 1 - k]) - float(ends[k]) > BLANK_STEPS * step:
        return ""
    level = float(np.median(sample))
    kind = ("a black frame" if level <= BLANK_STEPS * step
            else "a saturated frame" if level >= top - BLANK_STEPS * step else "a flat frame")
    value = f"{level:.0f}" if sample.dtype.kind != "f" else f"{level:.3g}"
    return f"every pixel is {value} ({kind})"


def _clearly_a_picture(arr: np.ndarray) -> bool:
    """A quick look at every 32nd row and column: over 1 % of them more than a tenth of
    the full scale from their median (no frame :func:`blank_frame` calls blank does)."""
    sparse = arr[::32, ::32].reshape(-1)
    if sparse.dtype.kind not in "uif" or sparse.size < 100:
        return False
    full = 1.0 if sparse.dtype.kind == "f" else float(np.iinfo(sparse.dtype).max)
    values = sparse.astype(np.float32)
    with np.errstate(invalid="ignore"):
        far = np.abs(values - median(values)) > 0.1 * full
    return int(np.count_nonzero(far)) > 0.01 * sparse.size


def mean_level(img: np.ndarray) -> float:
    """A frame's mean brightness as a fraction of its full scale (integer frames) or in
    its own values (float frames; NaN ignored), over every 8th row and column and all
    its channels: enough to tell a laser frame, dark but for its ring, from an LED
    frame (~20 us a 1224-px grey frame)."""
    sample = np.asarray(img)[::8, ::8]
    full = float(np.iinfo(sample.dtype).max) if sample.dtype.kind in "ui" else 1.0
    if sample.dtype.kind == "f":
        sample = sample[np.isfinite(sample)]
    return float(np.mean(sample, dtype=np.float64)) / full if sample.size else float("nan")


_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


def repair_pixels(grey: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``grey`` (2-D) with the pixels at ``rows``, ``cols`` replaced, in place, by the
    median of their 8 neighbours (clamped at the border): a sensor's hot and dead
    pixels. Returns ``grey``."""
    if len(rows) == 0:
        return grey
    r = np.clip(np.asarray(rows)[:, None] + _NEIGHBOURS[:, 0], 0, grey.shape[0] - 1)
    c = np.clip(np.asarray(cols)[:, None] + _NEIGHBOURS[:, 1], 0, grey.shape[1] - 1)
    grey[rows, cols] = np.median(grey[r, c], axis=1)
    return grey
