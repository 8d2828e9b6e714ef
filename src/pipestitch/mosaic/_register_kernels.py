"""Compiled inner loops of registration (numba): packed cross-power spectra, the
weighted correlation peak, the Lucas-Kanade polish of a sub-pixel shift, the tapered
registration image, which patches of two strips lie wholly on valid nodes, and a
link's patches cut out, gated by their contrast and less their weighted mean at once
(done per patch in Python, that bookkeeping cost nearly as much as the patch's
correlation).

Why hand-written: OpenCV has no modulus normalisation of its packed (CCS) spectra,
and the polish reads a cubic-shifted patch in one pass instead of warping a copy
(the same weights as ``cv2.warpAffine``'s cubic, to float32 rounding).

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def _unit(re: float, im: float) -> tuple[float, float]:
    """(re, im) / max(|re + i·im|, 1e-12) in float32.

    The modulus in float64, rounded once: what C's ``hypotf`` (``np.hypot`` of float32)
    returns for finite values, without its library call per element.
    """
    mag = max(F32(np.sqrt(np.float64(re) * np.float64(re) + np.float64(im) * np.float64(im))),
              F32(1e-12))
    return F32(re / mag), F32(im / mag)


@numba.njit(cache=True, nogil=True)
def _unit_cross(b_re: float, b_im: float, a_re: float, a_im: float) -> tuple[float, float]:
    """b·conj(a) / |b·conj(a)| (0 for a zero product), float32."""
    re = F32(b_re * a_re + b_im * a_im)
    im = F32(b_im * a_re - b_re * a_im)
    return _unit(re, im)


@numba.njit(cache=True, nogil=True)
def _unit_cross_pairs(b: np.ndarray, a: np.ndarray, out: np.ndarray, n_pairs: int) -> None:
    """:func:`_unit_cross` of the (re, im) pairs at columns (1 + 2k, 2 + 2k), k < n_pairs.

    A counted loop over the pairs, which the compiler vectorises (~4x faster than
    ``range(1, n - 1, 2)`` over a row; the same operations, the same values).
    """
    for k in range(n_pairs):
        c = 1 + 2 * k
        out[c], out[c + 1] = _unit_cross(b[c], b[c + 1], a[c], a[c + 1])


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
        _unit_cross_pairs(spec_b[r], spec_a[r], out[r], (n_cols - 1) // 2)
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
        for c in range(n_cols - sc):   # loops, not slice assignments: less to compile
            m[c] = src[sc + c]
        for c in range(sc):
            m[n_cols - sc + c] = src[c]
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


@numba.njit(cache=True, nogil=True)
def polish(first: np.ndarray, second: np.ndarray, weight: np.ndarray, dx: float, dy: float,
           iterations: int, noise: np.ndarray, a11: float, a12: float, a22: float,
           min_signal_share: float) -> tuple[float, float]:
    """Lucas-Kanade steps on a translation d with ``second(x) = first(x - d)`` (finite
    ``dx``, ``dy``; see :func:`pipestitch.mosaic.register.phase_shift`).

    ``a11``, ``a12``, ``a22``: ``first``'s :func:`gradient_moments` under ``weight``.
    ``noise``: empty, or what ``first``'s noise adds to the residual moments and to the
    Hessian's diagonal (d_x, d_y, h_x, h_y), subtracted from both unless that would
    leave less than ``min_signal_share`` of the Hessian. Stops when a step leaves the linear range
    (more than a pixel: the start is kept from there) or falls below 1e-3 px.
    """
    d_x = d_y = 0.0
    if noise.size and min(a11 - noise[2] - min_signal_share * a11,
                          a22 - noise[3] - min_signal_share * a22) > 0:
        a11, a22, d_x, d_y = a11 - noise[2], a22 - noise[3], noise[0], noise[1]
    det = a11 * a22 - a12 * a12
    if det <= 1e-12 * max(a11 * a22, 1e-30):
        return dx, dy
    n_rows, n_cols = second.shape
    for _ in range(iterations):
        # back(x) = second(x + d) = first(x - delta) ~ first(x) - grad(first) . delta
        if dx == np.floor(dx) and dy == np.floor(dy) and abs(dx) < n_cols and abs(dy) < n_rows:
            # Whole pixels (a correlation peak): cubic interpolation there is a copy,
            # so the moments read ``second`` shifted instead of a warped copy.
            bx, by = residual_moments(first, second, weight, int(dy), int(dx))
        else:
            bx, by = shifted_residual_moments(first, second, weight, dx, dy)
        bx, by = -(bx + d_x), -(by + d_y)
        step_x, step_y = (a22 * bx - a12 * by) / det, (a11 * by - a12 * bx) / det
        if abs(step_x) > 1 or abs(step_y) > 1:
            break
        dx, dy = dx + step_x, dy + step_y
        if abs(step_x) < 1e-3 and abs(step_y) < 1e-3:
            break
    return dx, dy


@numba.njit(cache=True, nogil=True)
def polish_patches(first: np.ndarray, second: np.ndarray, weight: np.ndarray,
                   shifts: np.ndarray, iterations: int, noise: np.ndarray,
                   min_signal_share: float) -> np.ndarray:
    """:func:`polish` of each pair of patches ``first[k]``, ``second[k]`` from
    ``shifts[k]`` (dx, dy), with ``noise[k]`` (none when ``noise`` has no rows); a
    non-finite start is kept. Returns the polished shifts (n, 2)."""
    out = shifts.copy()
    none = np.empty(0)
    for k in range(first.shape[0]):
        dx, dy = shifts[k, 0], shifts[k, 1]
        if not (np.isfinite(dx) and np.isfinite(dy)):
            continue
        a11, a12, a22 = gradient_moments(first[k], weight)
        out[k, 0], out[k, 1] = polish(first[k], second[k], weight, dx, dy, iterations,
                                      noise[k] if noise.shape[0] else none, a11, a12, a22,
                                      min_signal_share)
    return out


@numba.njit(cache=True, nogil=True)
def _copy_rows(strip: np.ndarray, row: int, col: int, out: np.ndarray) -> None:
    """``out`` = the strip's rows from ``row`` on (wrapping) and columns from ``col`` on,
    ``out``'s size (element loops, not slice assignments: less to compile)."""
    n_rows = strip.shape[0]
    for i in range(out.shape[0]):
        src, dst = strip[(row + i) % n_rows], out[i]
        for j in range(out.shape[1]):
            dst[j] = src[col + j]


@numba.njit(cache=True, nogil=True)
def _patch_std(patch: np.ndarray) -> float:
    """Standard deviation of a patch (float64 sums, as ``cv2.meanStdDev``; eight partial
    sums in a fixed order, so that they run side by side)."""
    flat = patch.ravel()
    total = np.zeros(8)
    squares = np.zeros(8)
    n = flat.size - flat.size % 8
    for i in range(0, n, 8):
        for lane in range(8):
            v = np.float64(flat[i + lane])
            total[lane] += v
            squares[lane] += v * v
    for i in range(n, flat.size):
        v = np.float64(flat[i])
        total[0] += v
        squares[0] += v * v
    mean = total.sum() / flat.size
    return np.sqrt(max(squares.sum() / flat.size - mean * mean, 0.0))


@numba.njit(cache=True, nogil=True)
def minus_weighted_mean(patch: np.ndarray, weight: np.ndarray, total: float) -> None:
    """``patch`` less its mean weighted by ``weight`` (flat, float32) whose sum is
    ``total``, in place: the dot product in float32 by BLAS (``numpy.dot``'s ``sdot``)."""
    flat = patch.ravel()
    mean = F32(np.float64(np.dot(weight, flat)) / total)
    for i in range(flat.size):
        flat[i] = flat[i] - mean


@numba.njit(cache=True, nogil=True)
def link_patches(first: np.ndarray, second: np.ndarray, valid: np.ndarray, step: int,
                 shift_rows: int, shift_cols: int, weight: np.ndarray, weight_total: float,
                 min_std: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The patches of a link that :func:`patches_valid` found valid, textured enough.

    Patch (k, m) of ``second`` starts at column ``k·step`` and row ``m·step`` (rows
    wrap), its counterpart in ``first`` ``shift_cols`` columns and ``shift_rows`` rows
    on; both are ``weight``'s size (square). A pair is kept when both standard
    deviations reach ``min_std``; each kept patch less its mean weighted by ``weight``
    (whose sum is ``weight_total``). Returns the first's and the second's patches
    (n, size, size) float32, in the order of ``numpy.nonzero(valid)``, and each pair's
    (row, column) in ``second`` and (row, column) in ``first`` (n, 4).
    """
    size = weight.shape[0]
    n_rows = second.shape[0]
    flat_weight = weight.ravel()
    count = 0
    for v in valid.ravel():
        count += v
    a = np.empty((count, size, size), np.float32)
    b = np.empty((count, size, size), np.float32)
    where = np.empty((count, 4), np.int64)
    n = 0
    for k in range(valid.shape[0]):
        for m in range(valid.shape[1]):
            if not valid[k, m]:
                continue
            c, r = k * step, m * step
            c1 = c + shift_cols
            _copy_rows(second, r, c, b[n])
            if _patch_std(b[n]) < min_std:
                continue
            _copy_rows(first, r + shift_rows, c1, a[n])
            if _patch_std(a[n]) < min_std:
                continue
            minus_weighted_mean(a[n], flat_weight, weight_total)
            minus_weighted_mean(b[n], flat_weight, weight_total)
            where[n, 0], where[n, 1] = r, c
            where[n, 2], where[n, 3] = (r + shift_rows) % n_rows, c1
            n += 1
    return a[:n], b[:n], where[:n]


@numba.njit(cache=True, nogil=True)
def patches_valid(first_valid: np.ndarray, second_valid: np.ndarray, size: int, step: int,
                  shift_rows: int, shift_cols: int) -> np.ndarray:
    """Which ``size`` x ``size`` patches of ``second_valid`` and their counterparts in
    ``first_valid`` are valid throughout: (column patches, row patches) booleans.

    Patch (k, m) of the second strip starts at column ``k·step`` and row ``m·step``;
    its counterpart in the first starts ``shift_cols`` columns and ``shift_rows`` rows
    on. Rows wrap around the pipe; columns do not: a counterpart past either end of
    the strip is not valid. Each test stops at the first invalid node.
    """
    n_rows, n_cols = second_valid.shape
    n_c = max(0, (n_cols - size) // step + 1)
    n_r = (n_rows + step - 1) // step
    out = np.zeros((n_c, n_r), np.bool_)
    for k in range(n_c):
        c, c1 = k * step, k * step + shift_cols
        if c1 < 0 or c1 + size > n_cols:
            continue
        for m in range(n_r):
            r = m * step
            out[k, m] = (_all_valid(second_valid, r, c, size)
                         and _all_valid(first_valid, r + shift_rows, c1, size))
    return out


@numba.njit(cache=True, nogil=True)
def _all_valid(valid: np.ndarray, row: int, col: int, size: int) -> bool:
    """Whether rows ``row .. row + size - 1`` (wrapping) of ``valid`` are valid in
    columns ``col .. col + size - 1``."""
    n_rows = valid.shape[0]
    for i in range(size):
        line = valid[(row + i) % n_rows]
        for j in range(col, col + size):
            if not line[j]:
                return False
    return True


@numba.njit(cache=True, nogil=True)
def tapered_image(contrast: np.ndarray, weight: np.ndarray, taper: np.ndarray) -> np.ndarray:
    """``contrast · clip(weight, 0, 1) · taper[column]`` in float32, as the numpy
    expression multiplies float32 arrays (a NaN weight stays NaN, as ``numpy.clip``
    leaves it)."""
    out = np.empty(contrast.shape, np.float32)
    for i in range(contrast.shape[0]):
        for j in range(contrast.shape[1]):
            w = weight[i, j]
            if w < F32(0):
                w = F32(0)
            elif w > F32(1):
                w = F32(1)
            out[i, j] = F32(contrast[i, j] * w) * taper[j]
    return out
