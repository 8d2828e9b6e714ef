"""Compiled inner loops of unwrapping, registration, occluders and the ring (numba).

Why hand-written: every LED frame is unwrapped three times per run and each strip
(about a million nodes at full size) then goes through a dozen whole-array passes
(upsampling the maps, masking, local contrast, spectra, the correlation peak, the
Lucas-Kanade polish); the laser ring and the occluder mask do the same on whole
frames. As numpy expressions each pass allocates and walks the array again and most
of the time goes to memory traffic; no library offers these fused steps (OpenCV's
resize/remap quantise interpolation weights to 1/32, see
:func:`pipestitch.unwrap.unwrap_maps`; it has no modulus normalisation of its packed
spectra; numpy's quantile over a frame stack sorts with one partition per pixel).
Each kernel is one plain loop, arrays in and arrays out, and releases the GIL
(``nogil``) so the worker threads run them side by side. The modules using them
(:mod:`pipestitch.unwrap`, :mod:`pipestitch.register`, :mod:`pipestitch.occluder`,
:mod:`pipestitch.ring`) hold the definitions and the logic around them;
``tests/test_strip_kernels.py`` compares every kernel with the expression it replaces.

Float32 arithmetic is kept where the numpy code it replaces was float32, in the
same order, so that maps, masks and quantiles are bitwise the same; sums are
accumulated in float64 (the registration moves by ~1e-8 px).
"""

from __future__ import annotations

import numba
import numpy as np

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def _interp_line(src: np.ndarray, step: int, w_lo: np.ndarray, w_hi: np.ndarray,
                 dst: np.ndarray) -> None:
    """``dst[c·step + k] = src[c]·w_lo[k] + src[c + 1]·w_hi[k]`` (``src[c]`` for k = 0)."""
    n, last = dst.shape[0], src.shape[0] - 1
    for c in range(last + 1):
        base = c * step
        a = src[c]
        if base < n:
            dst[base] = a
        if c == last:
            break
        b = src[c + 1]
        for k in range(1, min(step, n - base)):
            dst[base + k] = a * w_lo[k] + b * w_hi[k]


@numba.njit(cache=True, nogil=True)
def upsample_masked(nodes: np.ndarray, step: int, n_rows: int, n_cols: int,
                    ok_above: float) -> np.ndarray:
    """Bilinear upsampling of node fields, masked where the validity field is not ~1.

    ``nodes`` (F, rows, cols) float32 every ``step`` nodes (the last row/column is
    the last node); field 2 is the validity (1/0). Returns (F - 1, n_rows, n_cols)
    float32: fields 0 and 1 (map x, y) with -1 and the fields after the validity with
    0 where the interpolated validity is not above ``ok_above``. Rows first, then
    columns, with the weights (k / step as float32) of the numpy original; a node
    that falls on a grid node is copied (the original's ``a·1 + b·0``: the same for
    finite values).
    """
    n_f, last_r = nodes.shape[0], nodes.shape[1] - 1
    out = np.empty((n_f - 1, n_rows, n_cols), np.float32)
    w_hi = np.empty(step, np.float32)
    w_lo = np.empty(step, np.float32)
    for k in range(step):
        w_hi[k] = F32(k / step)
        w_lo[k] = F32(1) - w_hi[k]
    row = np.empty(nodes.shape[2], np.float32)
    valid = np.empty(n_cols, np.float32)
    ok_f = F32(ok_above)
    for i in range(n_rows):
        r0, k = min(i // step, last_r), i % step
        for order in range(n_f):   # the validity first: it masks the others
            f = 2 if order == 0 else (order - 1 if order <= 2 else order)
            if k == 0 or r0 == last_r:
                row[:] = nodes[f, r0]
            else:
                for c in range(row.shape[0]):
                    row[c] = nodes[f, r0, c] * w_lo[k] + nodes[f, r0 + 1, c] * w_hi[k]
            if f == 2:
                _interp_line(row, step, w_lo, w_hi, valid)
                continue
            dst = out[f if f < 2 else f - 1, i]
            _interp_line(row, step, w_lo, w_hi, dst)
            fill = F32(-1) if f < 2 else F32(0)
            for j in range(n_cols):
                if not valid[j] > ok_f:
                    dst[j] = fill
    return out



@numba.njit(cache=True, nogil=True)
def mask_strip(values: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, quality: np.ndarray,
               min_quality: float, occluded: np.ndarray) -> np.ndarray:
    """Mask a remapped strip in place and return its weight (``quality``, 0 where masked).

    A node is masked (NaN) where ``map_x`` < 0 (invisible), the value is not finite
    (outside the frame), ``quality`` < ``min_quality`` (float32 comparison) or the
    frame pixel nearest to it (rounded half to even, as ``cv2.remap`` with
    ``INTER_NEAREST`` does) is ``occluded`` or outside the frame; an empty
    ``occluded`` skips that last test.
    """
    weight = np.empty(values.shape, np.float32)
    q_min = F32(min_quality)
    check = occluded.size > 0
    height, width = occluded.shape
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            bad = map_x[i, j] < 0 or not np.isfinite(values[i, j]) or quality[i, j] < q_min
            if check and not bad:
                col, row = int(np.rint(map_x[i, j])), int(np.rint(map_y[i, j]))
                bad = not (0 <= col < width and 0 <= row < height) or occluded[row, col]
            if bad:
                values[i, j] = np.nan
                weight[i, j] = F32(0)
            else:
                weight[i, j] = quality[i, j]
    return weight


@numba.njit(cache=True, nogil=True)
def fill_invalid(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` with non-finite nodes set to 0, and the validity (1/0), both float32."""
    filled = np.empty(values.shape, np.float32)
    valid = np.empty(values.shape, np.float32)
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            ok = np.isfinite(values[i, j])
            filled[i, j] = values[i, j] if ok else F32(0)
            valid[i, j] = F32(1) if ok else F32(0)
    return filled, valid


@numba.njit(cache=True, nogil=True)
def contrast_of(filled: np.ndarray, valid: np.ndarray, support: np.ndarray,
                local: np.ndarray) -> np.ndarray:
    """value / local mean - 1 where valid (0 elsewhere); ``local`` is divided by the
    ``support`` (blurred validity) in place, making it the local mean. float32."""
    out = np.empty(filled.shape, np.float32)
    tiny = F32(1e-6)
    for i in range(filled.shape[0]):
        for j in range(filled.shape[1]):
            local[i, j] = local[i, j] / max(support[i, j], tiny)
            out[i, j] = filled[i, j] / max(local[i, j], tiny) - F32(1) if valid[i, j] else F32(0)
    return out


@numba.njit(cache=True, nogil=True)
def column_medians(values: np.ndarray, min_count: float) -> np.ndarray:
    """Median of the finite values of each column with more than ``min_count`` of them.

    NaN elsewhere. float32 values; an even count averages the two middle values in
    float32, as ``numpy.nanmedian`` does.
    """
    n_rows, n_cols = values.shape
    out = np.full(n_cols, np.nan)
    count = np.zeros(n_cols, np.int64)
    columns = np.empty((n_cols, n_rows), np.float32)   # finite values, column by column
    for i in range(n_rows):
        for j in range(n_cols):
            v = values[i, j]
            if np.isfinite(v):
                columns[j, count[j]] = v
                count[j] += 1
    for j in range(n_cols):
        n = count[j]
        if n > min_count:
            mid = n // 2
            part = np.partition(columns[j, :n], mid)
            if n % 2:
                out[j] = part[mid]
            else:
                out[j] = F32(part[:mid].max() + part[mid]) / F32(2)
    return out


# --- registration -----------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def _unit(re: float, im: float) -> tuple[float, float]:
    """(re, im) / max(|re + i·im|, 1e-12) in float32."""
    mag = max(F32(np.hypot(re, im)), F32(1e-12))
    return F32(re / mag), F32(im / mag)


@numba.njit(cache=True, nogil=True)
def _unit_cross(b_re: float, b_im: float, a_re: float, a_im: float) -> tuple[float, float]:
    """b·conj(a) / |b·conj(a)| (0 for a zero product), float32."""
    re = F32(b_re * a_re + b_im * a_im)
    im = F32(b_im * a_re - b_re * a_im)
    return _unit(re, im)


@numba.njit(cache=True, nogil=True)
def cross_power_ccs(spec_b: np.ndarray, spec_a: np.ndarray) -> np.ndarray:
    """Normalised cross-power spectrum b·conj(a) / |b·conj(a)| of two packed real spectra.

    Packed (CCS) layout of ``cv2.dft`` of a real image without
    ``DFT_COMPLEX_OUTPUT``: columns (2k-1, 2k) hold the real and imaginary parts of
    frequency k of every row; column 0, and the last column when the width is even,
    pack the purely real columns of the spectrum the same way down the rows (row 0
    real, rows (2m-1, 2m) a pair, the last row real when the height is even). The
    result is in the same layout, for ``cv2.idft(..., DFT_REAL_OUTPUT)``; the same as
    ``cv2.mulSpectrums(b, a, 0, conjB=True)`` then a division by the modulus.
    """
    n_rows, n_cols = spec_b.shape
    out = np.empty_like(spec_b)
    for r in range(n_rows):
        b, a, o = spec_b[r], spec_a[r], out[r]
        for c in range(1, n_cols - 1, 2):
            o[c], o[c + 1] = _unit_cross(b[c], b[c + 1], a[c], a[c + 1])
    for special in range(2 if n_cols % 2 == 0 and n_cols > 1 else 1):
        c = 0 if special == 0 else n_cols - 1
        out[0, c] = _unit(F32(spec_b[0, c] * spec_a[0, c]), F32(0))[0]
        for r in range(1, n_rows - 1, 2):
            out[r, c], out[r + 1, c] = _unit_cross(spec_b[r, c], spec_b[r + 1, c],
                                                   spec_a[r, c], spec_a[r + 1, c])
        if n_rows % 2 == 0 and n_rows > 1:
            last = n_rows - 1
            out[last, c] = _unit(F32(spec_b[last, c] * spec_a[last, c]), F32(0))[0]
    return out


@numba.njit(cache=True, nogil=True)
def weighted_peak(surface: np.ndarray, g_rows: np.ndarray, g_cols: np.ndarray,
                  floor: float) -> tuple[int, int]:
    """Row and column of the maximum of max(surface, 0)·(floor + (1 - floor)·g_rows·g_colsᵀ).

    float32 as the numpy expression it replaces; the first maximum in row-major order.
    Profile values below 1e-10 are flushed to 0 first: their products then add less
    than half an ulp to ``floor`` (the same weight), and denormal arithmetic is slow.
    """
    lo, hi = F32(floor), F32(1 - floor)
    g_c = np.where(g_cols < F32(1e-10), F32(0), g_cols)
    best, best_r, best_c = F32(-1), 0, 0
    for r in range(surface.shape[0]):
        gr = g_rows[r] if g_rows[r] >= F32(1e-10) else F32(0)
        for c in range(surface.shape[1]):
            v = max(surface[r, c], F32(0)) * (lo + hi * (gr * g_c[c]))
            if v > best:
                best, best_r, best_c = v, r, c
    return best_r, best_c


@numba.njit(cache=True, nogil=True)
def _row_gradients(img: np.ndarray, r: int, gx: np.ndarray, gy: np.ndarray) -> None:
    """Row ``r`` of ``numpy.gradient(img)`` (d/dcol into gx, d/drow into gy), float32."""
    n_rows, n_cols = img.shape
    cur = img[r]
    if n_cols > 1:
        gx[0] = cur[1] - cur[0]
        gx[n_cols - 1] = cur[n_cols - 1] - cur[n_cols - 2]
    else:
        gx[0] = F32(0)
    for c in range(1, n_cols - 1):
        gx[c] = (cur[c + 1] - cur[c - 1]) / F32(2)
    if n_rows == 1:
        gy[:] = F32(0)
    elif r == 0:
        for c in range(n_cols):
            gy[c] = img[1, c] - cur[c]
    elif r == n_rows - 1:
        for c in range(n_cols):
            gy[c] = cur[c] - img[r - 1, c]
    else:
        up, down = img[r - 1], img[r + 1]
        for c in range(n_cols):
            gy[c] = (down[c] - up[c]) / F32(2)


@numba.njit(cache=True, nogil=True)
def gradient_moments(img: np.ndarray, weight: np.ndarray) -> tuple[float, float, float]:
    """Weighted sums of gx², gx·gy and gy² of ``img`` (float64 accumulation).

    An empty ``weight`` weighs every pixel 1.
    """
    gx = np.empty(img.shape[1], np.float32)
    gy = np.empty(img.shape[1], np.float32)
    ones = np.ones(img.shape[1], np.float32)
    a11 = a12 = a22 = 0.0
    for r in range(img.shape[0]):
        _row_gradients(img, r, gx, gy)
        w = weight[r] if weight.size else ones
        for c in range(img.shape[1]):
            a11 += w[c] * gx[c] * gx[c]
            a12 += w[c] * gx[c] * gy[c]
            a22 += w[c] * gy[c] * gy[c]
    return a11, a12, a22


@numba.njit(cache=True, nogil=True)
def residual_moments(img: np.ndarray, moved: np.ndarray, weight: np.ndarray, shift_rows: int,
                     shift_cols: int) -> tuple[float, float]:
    """Weighted sums of (m - img)·gx and (m - img)·gy, gradients of ``img``.

    ``m`` is ``moved`` rolled back by whole pixels, wrapping: m[r, c] =
    moved[(r + shift_rows) % rows, (c + shift_cols) % cols]. An empty ``weight``
    weighs every pixel 1.
    """
    n_rows, n_cols = img.shape
    gx = np.empty(n_cols, np.float32)
    gy = np.empty(n_cols, np.float32)
    m = np.empty(n_cols, np.float32)
    ones = np.ones(n_cols, np.float32)
    sc = shift_cols % n_cols
    bx = by = 0.0
    for r in range(n_rows):
        _row_gradients(img, r, gx, gy)
        src = moved[(r + shift_rows) % n_rows]
        m[:n_cols - sc] = src[sc:]
        m[n_cols - sc:] = src[:sc]
        w, cur = weight[r] if weight.size else ones, img[r]
        for c in range(n_cols):
            e = w[c] * (m[c] - cur[c])
            bx += e * gx[c]
            by += e * gy[c]
    return bx, by

CUBIC_A = -0.75      # OpenCV's INTER_CUBIC (Keys) kernel parameter


@numba.njit(cache=True, nogil=True)
def _cubic_weights(f: float) -> np.ndarray:
    """Keys cubic weights (a = ``CUBIC_A``) of the taps at -1, 0, 1, 2 for a sample at
    fraction ``f`` (0 <= f < 1) past tap 0: OpenCV's ``interpolateCubic``."""
    a = CUBIC_A
    w = np.empty(4)
    x = f + 1.0
    w[0] = ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a
    w[1] = ((a + 2.0) * f - (a + 3.0)) * f * f + 1.0
    x = 1.0 - f
    w[2] = ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
    w[3] = 1.0 - w[0] - w[1] - w[2]
    return w


@numba.njit(cache=True, nogil=True)
def shifted_residual_moments(img: np.ndarray, moved: np.ndarray, weight: np.ndarray,
                             dx: float, dy: float) -> tuple[float, float]:
    """:func:`residual_moments` against ``moved`` moved back by a sub-pixel shift.

    m(r, c) is ``moved`` at (column c + dx, row r + dy), bicubic with OpenCV's kernel
    and wrapping on both axes: ``cv2.warpAffine(moved, [[1, 0, dx], [0, 1, dy]],
    INTER_CUBIC | WARP_INVERSE_MAP, BORDER_WRAP)`` then :func:`residual_moments`
    (equal to float32 rounding, tested), in one pass without the warped copy. The
    shift is the same everywhere, so are the weights: rows are interpolated along the
    columns once, then combined.
    """
    n_rows, n_cols = img.shape
    ix, iy = int(np.floor(dx)), int(np.floor(dy))
    wx, wy = _cubic_weights(dx - ix), _cubic_weights(dy - iy)
    # ``moved`` from row iy - 1 and column ix - 1 on, wrapped, 3 rows and columns more:
    # then every tap is a plain offset (no modulo in the loops below).
    cols = np.empty(n_cols + 3, np.int64)
    for c in range(n_cols + 3):
        cols[c] = ((c + ix - 1) % n_cols + n_cols) % n_cols
    along = np.empty((n_rows + 3, n_cols), np.float32)
    row = np.empty(n_cols + 3, np.float32)
    for r in range(n_rows + 3):
        src = moved[((r + iy - 1) % n_rows + n_rows) % n_rows]
        for c in range(n_cols + 3):
            row[c] = src[cols[c]]
        for c in range(n_cols):
            along[r, c] = (wx[0] * row[c] + wx[1] * row[c + 1] + wx[2] * row[c + 2]
                           + wx[3] * row[c + 3])
    gx = np.empty(n_cols, np.float32)
    gy = np.empty(n_cols, np.float32)
    ones = np.ones(n_cols, np.float32)
    bx = by = 0.0
    for r in range(n_rows):
        _row_gradients(img, r, gx, gy)
        a0, a1, a2, a3 = along[r], along[r + 1], along[r + 2], along[r + 3]
        w, cur = weight[r] if weight.size else ones, img[r]
        for c in range(n_cols):
            m = wy[0] * a0[c] + wy[1] * a1[c] + wy[2] * a2[c] + wy[3] * a3[c]
            e = w[c] * (m - cur[c])
            bx += e * gx[c]
            by += e * gy[c]
    return bx, by

# --- occluders --------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def quantile_over_frames(stack: np.ndarray, virtual: float,
                         median: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of an (n, H, W) float32 stack: its quantile and its median over frames.

    ``virtual`` is numpy's "linear" virtual index of the quantile, (n - 1)·q computed
    as ``numpy.quantile`` does; the interpolation between the two order statistics
    around it and the median (middle value, or the float32 mean of the two middle
    ones) follow ``numpy.quantile`` and ``numpy.median`` on float32 exactly. The
    median is computed only when asked (an empty array otherwise). Values must be
    finite.
    """
    n, height, width = stack.shape
    lo = min(max(int(np.floor(virtual)), 0), n - 1)
    hi = min(lo + 1, n - 1)
    gamma = virtual - np.floor(virtual)
    g, g1 = F32(gamma), F32(1 - gamma)
    quant = np.empty((height, width), np.float32)
    med = np.empty((height, width) if median else (0, 0), np.float32)
    buf = np.empty((n, width), np.float32)
    for i in range(height):
        buf[:, :] = stack[:, i, :]
        # Odd-even transposition sort of every pixel's n values at once: branch-free
        # and contiguous over the pixels of a row (an insertion sort per pixel is
        # several times slower on its mispredicted branches).
        for p in range(n):
            for k in range(p % 2, n - 1, 2):
                a, b = buf[k], buf[k + 1]
                for j in range(width):
                    x, y = a[j], b[j]
                    a[j] = min(x, y)
                    b[j] = max(x, y)
        for j in range(width):
            diff = buf[hi, j] - buf[lo, j]
            quant[i, j] = buf[hi, j] - diff * g1 if gamma >= 0.5 else buf[lo, j] + diff * g
            if median:
                mid = n // 2
                med[i, j] = buf[mid, j] if n % 2 else F32(buf[mid - 1, j] + buf[mid, j]) / F32(2)
    return quant, med


# --- laser ring -------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def divide_by_reflectance(polar: np.ndarray, local: np.ndarray, broad: np.ndarray,
                          floor: float, min_relative: float) -> np.ndarray:
    """``polar / max(local / broad, min_relative)`` where the wall is bright enough, else 0.

    Bright enough: ``local > floor·broad`` and ``broad > 0``. float32 throughout, as
    the numpy expression it replaces.
    """
    out = np.empty(polar.shape, np.float32)
    f, m = F32(floor), F32(min_relative)
    for i in range(polar.shape[0]):
        for j in range(polar.shape[1]):
            b, v = broad[i, j], local[i, j]
            if v > f * b and b > F32(0):
                out[i, j] = polar[i, j] / max(v / b, m)
            else:
                out[i, j] = F32(0)
    return out


@numba.njit(cache=True, nogil=True)
def ridge_peaks(ridge: np.ndarray, threshold: float,
                count: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` strongest local maxima of each row of ``ridge`` above ``threshold``.

    A local maximum is above its left neighbour and not below its right one, at
    least 2 samples from either end. Returns (index, value), (rows, count), strongest
    first; missing ones have index 0 and value -inf.
    """
    n_rows, n_cols = ridge.shape
    index = np.zeros((n_rows, count), np.int64)
    value = np.full((n_rows, count), -np.inf, np.float32)
    for i in range(n_rows):
        row = ridge[i]
        for j in range(2, n_cols - 2):
            v = row[j]
            if not (v > threshold and v > row[j - 1] and v >= row[j + 1]):
                continue
            if v <= value[i, count - 1]:
                continue
            k = count - 1
            while k > 0 and value[i, k - 1] < v:   # ties: the earlier sample first
                value[i, k] = value[i, k - 1]
                index[i, k] = index[i, k - 1]
                k -= 1
            value[i, k] = v
            index[i, k] = j
    return index, value


@numba.njit(cache=True, nogil=True)
def shaded_albedo(values: np.ndarray, shading: np.ndarray, level: np.ndarray,
                  weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values / max(shading · level[col], 1e-6)`` (float64 arithmetic, as numpy's
    promotion of the float32 strip by the float64 level) stored as float32, 0 where
    there is no data, and the validity (uint8: the albedo is finite and ``weight`` > 0).
    """
    n_rows, n_cols = values.shape
    albedo = np.empty((n_rows, n_cols), np.float32)
    valid = np.empty((n_rows, n_cols), np.uint8)
    for i in range(n_rows):
        for j in range(n_cols):
            v = values[i, j] / max(np.float64(shading[i, j]) * level[j], 1e-6)
            if np.isfinite(v) and weight[i, j] > 0:
                albedo[i, j] = F32(v)
                valid[i, j] = 1
            else:
                albedo[i, j] = F32(0)
                valid[i, j] = 0
    return albedo, valid


@numba.njit(cache=True, nogil=True)
def feathered_weight(weight: np.ndarray, feather: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``weight · feather`` (float32) where ``valid``, else 0."""
    out = np.empty(weight.shape, np.float32)
    for i in range(weight.shape[0]):
        for j in range(weight.shape[1]):
            out[i, j] = weight[i, j] * feather[i, j] if valid[i, j] else F32(0)
    return out


@numba.njit(cache=True, nogil=True)
def accumulate_strip(total: np.ndarray, weights: np.ndarray, col0: int, albedo: np.ndarray,
                     weight: np.ndarray, gain: float) -> None:
    """``total[:, col0:] += albedo · gain · weight`` and ``weights[:, col0:] += weight``
    in place over the strip's columns (float32 sums of float64 products)."""
    for i in range(albedo.shape[0]):
        for j in range(albedo.shape[1]):
            w = weight[i, j]
            if w != 0:
                total[i, col0 + j] = F32(np.float64(total[i, col0 + j])
                                         + np.float64(albedo[i, j]) * gain * np.float64(w))
                weights[i, col0 + j] += w


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
