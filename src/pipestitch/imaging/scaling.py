"""Integer frames to float32, scaled: numpy's values, in a quarter of its time.

``numpy.multiply(frame, float32(scale), dtype=float32)`` casts each value to float32
and multiplies in float32, through a buffer: ~0.3 ms for a 1224 x 1024 frame of 8 or
16 bits. A compiled loop doing the same float32 cast and product per pixel takes
~0.09 ms, with the same values to the bit (IEEE single arithmetic; tested). Every LED
frame is made float once per pass of the mosaic, and every laser frame once.
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

__all__ = ["scaled_float32"]


def scaled_float32(values: np.ndarray, scale: float,
                   out: np.ndarray | None = None) -> np.ndarray:
    """``numpy.multiply(values, numpy.float32(scale), dtype=numpy.float32, out=out)``.

    Parameters
    ----------
    values : numpy.ndarray
        The frame (any shape and dtype numpy multiplies).
    scale : float
        The factor, rounded to float32 first.
    out : numpy.ndarray, optional
        Where the result goes (numpy's rules).

    Returns
    -------
    numpy.ndarray
        float32; ``out`` when given. Compiled for a 2-D C-ordered 8- or 16-bit unsigned
        frame (into a C-ordered float32 ``out`` of its shape, or a new one); numpy
        otherwise.
    """
    factor = np.float32(scale)
    fits = out is None or (out.dtype == np.float32 and out.shape == values.shape
                           and out.flags.c_contiguous and out.flags.writeable)
    if (values.ndim == 2 and values.dtype in (np.uint8, np.uint16)
            and values.flags.c_contiguous and fits):
        target = np.empty(values.shape, np.float32) if out is None else out
        _scaled(values, factor, target)
        return target
    return np.multiply(values, factor, dtype=np.float32, out=out)


@numba.njit(cache=True, nogil=True)
def _scaled(values: np.ndarray, factor: np.float32, out: np.ndarray) -> None:
    """``out = float32(values) * factor``, pixel by pixel (float32 arithmetic)."""
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            out[i, j] = np.float32(values[i, j]) * factor
