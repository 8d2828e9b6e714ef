"""Compiled conversion of a float mosaic to 8 bits with no-data kept at 0 (numba).

Why hand-written: one pass instead of numpy's four temporaries over a mosaic that can
be hundreds of megapixels (``cv2.convertScaleAbs`` has no NaN-to-0 rule).

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def scaled_uint8(image: np.ndarray, scale: float) -> np.ndarray:
    """``clip(rint(image / scale · 250), 1, 255)`` as uint8 (float32 arithmetic, as numpy's
    on a float32 image), 0 where ``image`` is not finite (no data)."""
    out = np.empty(image.shape, np.uint8)
    s, k = F32(scale), F32(250)
    for i in range(image.shape[0]):
        for j in range(image.shape[1]):
            v = F32(image[i, j])
            if np.isfinite(v):
                q = np.rint(F32(v / s) * k)
                out[i, j] = np.uint8(min(max(q, F32(1)), F32(255)))
            else:
                out[i, j] = 0
    return out
