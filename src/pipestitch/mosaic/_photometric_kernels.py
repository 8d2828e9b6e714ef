"""Compiled inner loops of the photometric comparison strips' local contrast (numba).

Why hand-written: :func:`pipestitch.mosaic.photometric._contrast` took about ten
array expressions over a strip (validity, filled values, the local mean's division,
the contrast, three darkness tests, the final mask), each a temporary array; compiled
passes before (:func:`pipestitch.mosaic._unwrap_kernels.fill_invalid`, the unwrap's
own) and after OpenCV's blurs and dilation do the same float32 arithmetic in the same
order, pixel by pixel. Two strips a frame, in the pose pass.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

F32 = np.float32
FLOOR = F32(1e-6)        # the local mean's and the weight's floor (numpy: float32)
DARK_SHARE = F32(0.3)    # a node darker than this share of its local mean is dark
MIN_WEIGHT = F32(0.5)    # nodes with less of their neighbourhood valid are masked


@numba.njit(cache=True, nogil=True)
def contrast_and_dark(filled: np.ndarray, blurred: np.ndarray, weight: np.ndarray,
                      valid: np.ndarray, dark_level: np.float32
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Local contrast ``filled / max(local, 1e-6) - 1`` with the local mean ``local =
    blurred / max(weight, 1e-6)``, and the dark nodes (uint8 1): invalid, under 0.3 of
    their local mean, or a local mean under ``dark_level``; float32 throughout."""
    contrast = np.empty(filled.shape, np.float32)
    dark = np.empty(filled.shape, np.uint8)
    for i in range(filled.shape[0]):
        for j in range(filled.shape[1]):
            local = blurred[i, j] / max(weight[i, j], FLOOR)
            value = filled[i, j]
            contrast[i, j] = value / max(local, FLOOR) - F32(1)
            gone = valid[i, j] == 0 or value < DARK_SHARE * local or local < dark_level
            dark[i, j] = 1 if gone else 0
    return contrast, dark


@numba.njit(cache=True, nogil=True)
def masked_contrast(contrast: np.ndarray, dark: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``contrast`` with NaN where ``dark`` (nonzero) or ``weight`` < 0.5, in place."""
    for i in range(contrast.shape[0]):
        for j in range(contrast.shape[1]):
            if dark[i, j] != 0 or weight[i, j] < MIN_WEIGHT:
                contrast[i, j] = np.nan
    return contrast
