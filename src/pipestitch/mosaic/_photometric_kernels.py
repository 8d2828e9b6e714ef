"""Compiled inner loops of the photometric comparison strips (numba): their local
contrast, and the modulus of a packed cross-power spectrum (:func:`ccs_modulus`).

Why hand-written: :func:`pipestitch.mosaic.photometric._contrast` took about ten
array expressions over a strip (validity, filled values, the local mean's division,
the contrast, three darkness tests, the final mask), each a temporary array; compiled
passes before (:func:`pipestitch.mosaic._unwrap_kernels.fill_invalid`, the unwrap's
own) and after OpenCV's blurs and dilation do the same float32 arithmetic in the same
order, pixel by pixel. Two strips a frame, in the pose pass. OpenCV computes the
modulus inside ``cv2.phaseCorrelate`` (its ``magSpectrums``) but does not expose it:
:func:`ccs_modulus` is that loop, so that each strip's spectrum can be computed once
(:mod:`pipestitch.mosaic.photometric`) and the correlation's response is still
``cv2.phaseCorrelate``'s to the bit.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

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


@numba.njit(cache=True, nogil=True)
def _modulus(re: np.float32, im: np.float32) -> np.float32:
    """|re + i·im| as OpenCV's ``magSpectrums`` computes it: in float64, rounded once."""
    return F32(np.sqrt(np.float64(re) * np.float64(re) + np.float64(im) * np.float64(im)))


@numba.njit(cache=True, nogil=True)
def ccs_modulus(spectrum: np.ndarray) -> np.ndarray:
    """The modulus of a packed (CCS) spectrum in its own layout (float32): each (re, im)
    pair's modulus where its real part is, 0 where its imaginary part is, and the
    absolute value of the purely real entries (OpenCV's ``magSpectrums`` of a
    one-channel spectrum, which ``cv2.divSpectrums`` then divides by).

    The layout: columns (2k - 1, 2k) hold frequency k of every row; column 0, and the
    last column when the width is even, pack the purely real columns of the spectrum
    down the rows (row 0 real, rows (2m - 1, 2m) a pair, the last row real when the
    height is even). The pairs of a row in a counted loop, which the compiler vectorises.
    """
    n_rows, n_cols = spectrum.shape
    out = np.zeros_like(spectrum)
    n_pairs = (n_cols - 1) // 2
    for r in range(n_rows):
        row, dst = spectrum[r], out[r]
        for k in range(n_pairs):
            c = 1 + 2 * k
            dst[c] = _modulus(row[c], row[c + 1])
    for special in range(2 if n_cols % 2 == 0 and n_cols > 1 else 1):
        c = 0 if special == 0 else n_cols - 1
        out[0, c] = abs(spectrum[0, c])
        for r in range(1, n_rows - 1, 2):
            out[r, c] = _modulus(spectrum[r, c], spectrum[r + 1, c])
        if n_rows % 2 == 0 and n_rows > 1:
            out[n_rows - 1, c] = abs(spectrum[n_rows - 1, c])
    return out
