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

__all__ = ["to_grey"]


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
        A float32 (H, W) array that a grey integer frame is written into (see
        :mod:`pipestitch._runtime.scratch`); other frames get a new array.

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
        return np.multiply(arr, np.float32(scale), dtype=np.float32, out=out)
    arr = arr.astype(np.float32)
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr[..., :3], cv2.COLOR_BGR2GRAY) if arr.shape[2] >= 3 else arr[..., 0]
    arr = np.multiply(arr, np.float32(scale), out=arr if arr.flags.writeable else None)
    # Only a float frame can hold NaN or infinities.
    return arr if integer else np.nan_to_num(arr, nan=0.0, posinf=0.0, neginf=0.0)
