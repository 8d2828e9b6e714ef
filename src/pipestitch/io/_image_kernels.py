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
    1.9 ms on a Sub-filtered 1224 x 1024 grey frame, this one 0.35 ms), and four
    Paeth-filtered rows in a row are unfiltered together (:func:`_paeth_rows`)."""
    skip = 0
    for y in range(n_rows):
        if skip:
            skip -= 1
            continue
        kind = raw[y * (row_bytes + 1)]
        src, dst = y * (row_bytes + 1) + 1, y * row_bytes
        if kind == 0 or (kind == 2 and y == 0):
            for x in range(row_bytes):
                out[dst + x] = raw[src + x]
        elif kind == 1:
            _sub_row(raw, src, out, dst, row_bytes, pixel_bytes)
        elif kind == 2:
            _up_row(raw, src, out, dst, row_bytes)
        elif kind == 3:
            _average_row(raw, src, out, dst, row_bytes, pixel_bytes, y > 0)
        elif kind == 4:
            if _four_paeth_rows(raw, y, n_rows, row_bytes, pixel_bytes):
                _paeth_rows(raw, src, out, dst, row_bytes)
                skip = PAETH_ROWS - 1
            else:
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
    row, cur = raw[src:src + n], out[dst:dst + n]
    for k in range(min(step, n)):   # each byte of a pixel its own chain, in a register
        left = np.uint8(0)
        for x in range(k, n, step):
            left = np.uint8(row[x] + left)
            cur[x] = left


@numba.njit(cache=True, nogil=True, inline="always")
def _up_row(raw: np.ndarray, src: int, out: np.ndarray, dst: int, n: int) -> None:
    """An Up-filtered row below another: each byte plus the one above it. Through views
    indexed from 0, which LLVM vectorises (an index with an offset carries numba's
    negative-index test: 0.52 -> 0.06 ms for a 1224 x 1024 grey frame)."""
    row, up, cur = raw[src:src + n], out[dst - n:dst], out[dst:dst + n]
    for x in range(n):
        cur[x] = np.uint8(row[x] + up[x])


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
    if not has_above:   # upper and upper-left 0: the predictor is the left byte
        _sub_row(raw, src, out, dst, n, step)
        return
    row, up, cur = raw[src:src + n], out[dst - n:dst], out[dst:dst + n]
    if step == 1:   # the left and upper-left bytes carried in registers
        left, corner = np.int32(0), np.int32(0)
        for x in range(n):
            left, corner = _paeth_byte(row, up, cur, x, left, corner)
        return
    for x in range(min(step, n)):   # left and upper-left 0: the predictor is the upper byte
        cur[x] = np.uint8((np.int32(row[x]) + np.int32(up[x])) & 255)
    for x in range(step, n):
        _paeth_byte(row, up, cur, x, np.int32(cur[x - step]), np.int32(up[x - step]))


PAETH_ROWS = 4   # Paeth rows unfiltered together: four dependency chains side by side


@numba.njit(cache=True, nogil=True, inline="always")
def _four_paeth_rows(raw: np.ndarray, y: int, n_rows: int, row_bytes: int,
                     pixel_bytes: int) -> bool:
    """Whether rows ``y`` to ``y + 3`` are Paeth-filtered single-byte-pixel rows below
    another row, at least ``PAETH_ROWS`` bytes long (what :func:`_paeth_rows` takes)."""
    if pixel_bytes != 1 or y == 0 or y + PAETH_ROWS > n_rows or row_bytes < PAETH_ROWS:
        return False
    for k in range(PAETH_ROWS):
        if raw[(y + k) * (row_bytes + 1)] != 4:
            return False
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _paeth_rows(raw: np.ndarray, src: int, out: np.ndarray, dst: int, n: int) -> None:
    """``PAETH_ROWS`` Paeth-filtered rows of single-byte pixels, the first below another
    row, each one byte behind the row above it.

    A row's bytes form one chain (each needs its left neighbour), but a byte needs of
    the row above only the bytes above and above-left of it: so row k unfilters byte
    s - k while row 0 unfilters byte s, and the four chains overlap in the processor
    (a 1224 x 1024 grey frame Paeth-filtered throughout, with the same predictor: 2.7 ms
    a row at a time, 1.2-1.3 ms four at once; the same bytes, in an order the filter
    allows).
    """
    m = n + 1
    r0, r1 = raw[src:src + n], raw[src + m:src + m + n]
    r2, r3 = raw[src + 2 * m:src + 2 * m + n], raw[src + 3 * m:src + 3 * m + n]
    up, c0, c1 = out[dst - n:dst], out[dst:dst + n], out[dst + n:dst + 2 * n]
    c2, c3 = out[dst + 2 * n:dst + 3 * n], out[dst + 3 * n:dst + 4 * n]
    z = np.int32(0)
    l0, k0, l1, k1, l2, k2, l3, k3 = z, z, z, z, z, z, z, z
    for s in range(3):   # rows 1-3 start one byte after the row above
        l0, k0 = _paeth_byte(r0, up, c0, s, l0, k0)
        if s >= 1:
            l1, k1 = _paeth_byte(r1, c0, c1, s - 1, l1, k1)
        if s >= 2:
            l2, k2 = _paeth_byte(r2, c1, c2, s - 2, l2, k2)
    for s in range(n - 3):   # indices from 0 (no negative-index test to keep)
        l0, k0 = _paeth_byte(r0, up, c0, s + 3, l0, k0)
        l1, k1 = _paeth_byte(r1, c0, c1, s + 2, l1, k1)
        l2, k2 = _paeth_byte(r2, c1, c2, s + 1, l2, k2)
        l3, k3 = _paeth_byte(r3, c2, c3, s, l3, k3)
    for s in range(3):   # ... and end one byte after it
        if s == 0:
            l1, k1 = _paeth_byte(r1, c0, c1, n - 1, l1, k1)
        if s <= 1:
            l2, k2 = _paeth_byte(r2, c1, c2, n - 2 + s, l2, k2)
        l3, k3 = _paeth_byte(r3, c2, c3, n - 3 + s, l3, k3)


@numba.njit(cache=True, nogil=True, inline="always")
def _paeth_byte(row: np.ndarray, up: np.ndarray, cur: np.ndarray, x: int, left: np.int32,
                corner: np.int32) -> tuple[np.int32, np.int32]:
    """Byte ``x`` of a Paeth-filtered row (``row`` filtered, ``up`` the row above
    unfiltered, ``cur`` this row's output) from its unfiltered ``left`` and upper-left
    (``corner``) neighbours; returns (the byte, the byte above it): with single-byte
    pixels, byte ``x + 1``'s left and upper-left."""
    above = np.int32(up[x])
    value = (np.int32(row[x]) + _paeth(left, above, corner)) & 255
    cur[x] = np.uint8(value)
    return value, above


@numba.njit(cache=True, nogil=True, inline="always")
def _paeth(left: np.int32, above: np.int32, corner: np.int32) -> np.int32:
    """The Paeth predictor: whichever of ``left``, ``above`` and ``corner`` is nearest
    left + above - corner, ties in that order (PNG spec, section 9.4), for bytes.

    Computed without the three distances: the larger of left and above where
    3 corner - (left + above) is at most the smaller, else the smaller where the larger
    is at most that, else corner (tests/io/test_image_kernels.py checks it against the
    spec's form on all 2^24 byte triples). Fewer operations on the chain through the
    left byte, and selections rather than branches: a Paeth-filtered grey 1224 x 1024
    frame 5.5-5.9 -> 2.7 ms a row at a time.
    """
    threshold = 3 * corner - (left + above)
    low, high = min(left, above), max(left, above)
    return high if threshold <= low else (low if high <= threshold else corner)


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
