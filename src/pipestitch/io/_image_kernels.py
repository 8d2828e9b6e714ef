"""Compiled image loops (numba): a float mosaic to 8 bits with no-data kept at 0, and a
PNG's scanlines unfiltered and filtered.

Why hand-written: the mosaic's conversion is one pass instead of numpy's four
temporaries over a mosaic that can be hundreds of megapixels (``cv2.convertScaleAbs``
has no NaN-to-0 rule). No library unfilters a PNG's inflated scanlines on their own
(libpng and libspng do it inside their decoders, a byte at a time through row
callbacks), nor filters them apart from compressing them (libpng chooses a filter for
every row by trying each); :mod:`pipestitch.io.png` says why the frames are decoded,
and the mosaic's PNGs encoded, that way.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

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


@numba.njit(cache=True, nogil=True)
def png_unfilter(raw: np.ndarray, n_rows: int, row_bytes: int, pixel_bytes: int,
                 out: np.ndarray) -> bool:
    """Undo a PNG's per-scanline filters (PNG spec, section 9: None, Sub, Up, Average,
    Paeth) of ``raw`` (the inflated image data: each of ``n_rows`` scanlines one filter
    byte then ``row_bytes`` bytes) into ``out`` (``n_rows * row_bytes`` bytes), with
    ``pixel_bytes`` bytes a pixel (at least 1). False, ``out`` part-written, at a filter
    byte above 4. Each filter has its own loop; for single-byte pixels the byte to the
    left is carried in a register instead of read back from ``out`` (a store and a load
    in every step of the row's dependency chain: a first version that read it back took
    1.9 ms on a Sub-filtered 1224 x 1024 grey frame, this one 0.35 ms)."""
    for y in range(n_rows):
        kind = raw[y * (row_bytes + 1)]
        src, dst = y * (row_bytes + 1) + 1, y * row_bytes
        if kind == 0 or (kind == 2 and y == 0):
            for x in range(row_bytes):
                out[dst + x] = raw[src + x]
        elif kind == 1:
            _sub_row(raw, src, out, dst, row_bytes, pixel_bytes)
        elif kind == 2:
            for x in range(row_bytes):
                out[dst + x] = np.uint8(raw[src + x] + out[dst - row_bytes + x])
        elif kind == 3:
            _average_row(raw, src, out, dst, row_bytes, pixel_bytes, y > 0)
        elif kind == 4:
            _paeth_row(raw, src, out, dst, row_bytes, pixel_bytes, y > 0)
        else:
            return False
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _sub_row(raw: np.ndarray, src: int, out: np.ndarray, dst: int, n: int,
             step: int) -> None:
    """A Sub-filtered row: each byte plus the one ``step`` to its left."""
    if step == 1:
        left = np.uint8(0)
        for x in range(n):
            left = np.uint8(raw[src + x] + left)
            out[dst + x] = left
        return
    for x in range(n):
        out[dst + x] = raw[src + x] if x < step else np.uint8(raw[src + x] + out[dst + x - step])


@numba.njit(cache=True, nogil=True, inline="always")
def _average_row(raw: np.ndarray, src: int, out: np.ndarray, dst: int, n: int,
                 step: int, has_above: bool) -> None:
    """An Average-filtered row: each byte plus the floored mean of its left and upper
    neighbours (0 outside the image)."""
    left = np.int32(0)
    for x in range(n):
        above = np.int32(out[dst - n + x]) if has_above else np.int32(0)
        if step > 1:
            left = np.int32(out[dst + x - step]) if x >= step else np.int32(0)
        value = np.uint8((np.int32(raw[src + x]) + ((left + above) >> 1)) & 255)
        out[dst + x] = value
        left = np.int32(value)


@numba.njit(cache=True, nogil=True, inline="always")
def _paeth_row(raw: np.ndarray, src: int, out: np.ndarray, dst: int, n: int,
               step: int, has_above: bool) -> None:
    """A Paeth-filtered row: each byte plus whichever of its left, upper and upper-left
    neighbours (0 outside the image) is nearest left + upper - upper-left, ties in that
    order (:func:`_paeth`)."""
    left = corner = np.int32(0)
    for x in range(n):
        above = np.int32(out[dst - n + x]) if has_above else np.int32(0)
        if step > 1:
            inside = x >= step
            left = np.int32(out[dst + x - step]) if inside else np.int32(0)
            corner = np.int32(out[dst - n + x - step]) if inside and has_above else np.int32(0)
        value = np.uint8((np.int32(raw[src + x]) + _paeth(left, above, corner)) & 255)
        out[dst + x] = value
        left, corner = np.int32(value), above


@numba.njit(cache=True, nogil=True, inline="always")
def _paeth(left: np.int32, above: np.int32, corner: np.int32) -> np.int32:
    """The Paeth predictor: whichever of ``left``, ``above`` and ``corner`` is nearest
    left + above - corner, ties in that order."""
    p = left + above - corner
    pa, pb, pc = abs(p - left), abs(p - above), abs(p - corner)
    return left if pa <= pb and pa <= pc else (above if pb <= pc else corner)


@numba.njit(cache=True, nogil=True)
def png_paeth_filter(image: np.ndarray, pixel_bytes: int) -> np.ndarray:
    """A PNG's scanlines of the 8-bit ``image`` (rows, row bytes), each Paeth-filtered
    (PNG spec, section 9.4): a filter byte 4, then each byte minus the :func:`_paeth`
    prediction from its left, upper and upper-left neighbours (``pixel_bytes`` to the
    left; 0 outside the image). What :func:`png_unfilter` undoes."""
    n_rows, n = image.shape
    out = np.empty((n_rows, n + 1), np.uint8)
    for y in range(n_rows):
        out[y, 0] = 4
        for x in range(n):
            left = np.int32(image[y, x - pixel_bytes]) if x >= pixel_bytes else np.int32(0)
            above = np.int32(image[y - 1, x]) if y > 0 else np.int32(0)
            corner = (np.int32(image[y - 1, x - pixel_bytes]) if y > 0 and x >= pixel_bytes
                      else np.int32(0))
            out[y, x + 1] = np.uint8((np.int32(image[y, x]) - _paeth(left, above, corner)) & 255)
    return out
