"""The compiled registration kernels against the numpy/OpenCV expressions they replace."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.mosaic._register_kernels import (
    cross_power_ccs,
    gradient_moments,
    link_patches,
    patches_valid,
    polish,
    polish_patches,
    residual_moments,
    shifted_residual_moments,
    tapered_image,
)

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("shape", [(64, 48), (63, 48), (64, 47), (63, 47), (2, 9)])
def test_packed_cross_power_equals_the_complex_form(shape: tuple[int, int]) -> None:
    # The packed layout has special rows and columns that depend on the parity of each size.
    a = RNG.normal(size=shape).astype(np.float32)
    b = np.roll(a, (1, 3), axis=(0, 1)) + 0.1 * RNG.normal(size=shape).astype(np.float32)
    fa, fb = (cv2.dft(x, flags=cv2.DFT_COMPLEX_OUTPUT) for x in (a, b))
    cross = cv2.mulSpectrums(fb, fa, 0, conjB=True)
    cross /= np.maximum(np.hypot(cross[..., 0], cross[..., 1]), 1e-12)[..., None]
    want = cv2.idft(cross, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    got = cv2.idft(cross_power_ccs(cv2.dft(b), cv2.dft(a)),
                   flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    # A unit-modulus spectrum: the surface sums to ~1, float32 rounding ~1e-7.
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-6)


@pytest.mark.parametrize("n_cols", [48, 47, 3, 2, 1])
def test_packed_cross_power_pairs_are_the_float32_expression_to_the_bit(n_cols: int) -> None:
    # The (re, im) columns, which a vectorised loop computes: numpy's float32 products
    # and sums in the same order, the modulus in float64 rounded once.
    a = RNG.normal(size=(16, n_cols)).astype(np.float32)
    b = RNG.normal(size=(16, n_cols)).astype(np.float32)
    a[3] = 0    # zero products: the 1e-12 floor
    fa, fb = cv2.dft(a), cv2.dft(b)
    a_re, a_im, b_re, b_im = fa[:, 1:-1:2], fa[:, 2::2], fb[:, 1:-1:2], fb[:, 2::2]
    n = (n_cols - 1) // 2
    a_re, a_im, b_re, b_im = a_re[:, :n], a_im[:, :n], b_re[:, :n], b_im[:, :n]
    re = b_re * a_re + b_im * a_im
    im = b_im * a_re - b_re * a_im
    mag = np.maximum(np.sqrt(re.astype(float) ** 2 + im.astype(float) ** 2).astype(np.float32),
                     np.float32(1e-12))
    got = cross_power_ccs(fb, fa)
    assert np.array_equal(got[:, 1:1 + 2 * n:2], re / mag)
    assert np.array_equal(got[:, 2:2 + 2 * n:2], im / mag)


def test_gradient_moments_are_numpy_gradient_sums() -> None:
    img = RNG.normal(size=(31, 45)).astype(np.float32)
    weight = RNG.random(img.shape).astype(np.float32)
    gy, gx = np.gradient(img)
    want = [np.sum(weight.astype(float) * v) for v in (gx * gx, gx * gy, gy * gy)]
    np.testing.assert_allclose(gradient_moments(img, weight), want, rtol=1e-5)
    unweighted = gradient_moments(img, np.zeros((0, 0), np.float32))
    np.testing.assert_allclose(unweighted, [np.sum(v) for v in (gx * gx, gx * gy, gy * gy)],
                               rtol=1e-5)


@pytest.mark.parametrize(("d_rows", "d_cols"), [(0, 0), (3, -7), (-12, 20), (30, -44)])
def test_residual_moments_read_a_whole_pixel_shift_as_the_warp_gives_it(
        d_rows: int, d_cols: int) -> None:
    img = RNG.normal(size=(31, 45)).astype(np.float32)
    moved = RNG.normal(size=img.shape).astype(np.float32)
    weight = RNG.random(img.shape).astype(np.float32)
    # back(x) = moved(x + d), wrapping: what _polish warps (cubic, exact at whole pixels).
    back = cv2.warpAffine(moved, np.float32([[1, 0, d_cols], [0, 1, d_rows]]), (45, 31),
                          flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_WRAP)
    assert residual_moments(img, moved, weight, d_rows, d_cols) == \
        residual_moments(img, back, weight, 0, 0)
    gy, gx = np.gradient(img)
    err = weight.astype(float) * (back - img)
    np.testing.assert_allclose(residual_moments(img, back, weight, 0, 0),
                               [np.sum(err * gx), np.sum(err * gy)], rtol=1e-5)


@pytest.mark.parametrize(("dx", "dy"), [(0.3, -0.7), (2.25, 1.5), (-20.2, 30.6), (44.5, -10.25),
                                        (3.0, -2.0)])


@pytest.mark.parametrize("weighted", [True, False])
def test_shifted_residual_moments_are_the_cubic_warp_s(dx: float, dy: float,
                                                       weighted: bool) -> None:
    """The fused kernel equals cv2.warpAffine (INTER_CUBIC, wrapping) + residual_moments,
    sub-pixel and whole-pixel shifts, positive and negative, beyond half the size."""
    img = cv2.GaussianBlur(RNG.normal(size=(31, 45)).astype(np.float32), (0, 0), 1.2)
    moved = cv2.GaussianBlur(RNG.normal(size=img.shape).astype(np.float32), (0, 0), 1.2)
    weight = (RNG.random(img.shape).astype(np.float32) if weighted
              else np.zeros((0, 0), np.float32))
    back = cv2.warpAffine(moved, np.float32([[1, 0, dx], [0, 1, dy]]), (45, 31),
                          flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_WRAP)
    np.testing.assert_allclose(shifted_residual_moments(img, moved, weight, dx, dy),
                               residual_moments(img, back, weight, 0, 0), rtol=2e-5,
                               atol=1e-6)


@pytest.mark.parametrize(("shape", "shift"), [((100, 90), (3, 5)), ((100, 90), (-7, -20)),
                                              ((64, 64), (0, 0)), ((50, 40), (60, 1)),
                                              ((97, 150), (-130, 30))])
def test_patch_validity_is_the_wrapped_fancy_index_test(shape: tuple[int, int],
                                                        shift: tuple[int, int]) -> None:
    # The test it replaces: rows wrapped by modulo, columns cut; sizes smaller than
    # the patch give no patch at all.
    size, step = 16, 12
    first, second = (RNG.random(shape) > 0.002 for _ in range(2))
    second[:, 30:33] = False
    dr, dc = shift
    want = []
    for c in range(0, shape[1] - size + 1, step):
        col = []
        for r in range(0, shape[0], step):
            rows_j = np.arange(r, r + size) % shape[0]
            rows_i = (rows_j + dr) % shape[0]
            col.append(0 <= c + dc and c + dc + size <= shape[1]
                       and bool(second[rows_j, c:c + size].all())
                       and bool(first[rows_i, c + dc:c + dc + size].all()))
        want.append(col)
    got = patches_valid(first, second, size, step, dr, dc)
    np.testing.assert_array_equal(got, np.array(want, bool).reshape(got.shape))
    assert got.any() or shape[1] < size
    assert patches_valid(first[:, :10], second[:, :10], size, step, dr, dc).size == 0


def test_tapered_image_is_the_float32_expression() -> None:
    contrast = RNG.normal(size=(40, 30)).astype(np.float32)
    weight = RNG.uniform(-0.5, 1.5, (40, 30)).astype(np.float32)
    weight[3, 4] = np.nan
    taper = np.hanning(32)[1:-1].astype(np.float32)
    want = (contrast * np.clip(weight, 0, 1) * taper[None, :]).astype(np.float32)
    got = tapered_image(contrast, weight, taper)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got[3, 4]) and np.any(got == 0)


def _textured(shape: tuple[int, int]) -> np.ndarray:
    return cv2.GaussianBlur(RNG.normal(size=shape).astype(np.float32), (0, 0), 1.5)


@pytest.mark.parametrize("shift", [(5, 12), (-70, -3), (0, 0)])
def test_link_patches_are_the_fancy_indexed_patches_less_their_weighted_mean(
        shift: tuple[int, int]) -> None:
    # What each patch of a link was before: rows wrapped by fancy indexing, gated by
    # cv2.meanStdDev, less numpy.dot's weighted mean (the same BLAS dot, to the bit).
    size, step, min_std = 16, 12, 0.05
    second = _textured((60, 70))
    first = np.roll(second, (-shift[0], -shift[1]), axis=(0, 1))
    second[10:50, 20:60] *= np.float32(0.01)   # flat: some patches gated out, by either
    first[:30, :35] *= np.float32(0.01)
    valid = patches_valid(np.ones(first.shape, bool), np.ones(second.shape, bool), size,
                          step, *shift)
    weight = cv2.createHanningWindow((size, size), cv2.CV_32F)
    total = float(weight.sum(dtype=np.float64))
    a, b, where = link_patches(first, second, valid, step, *shift, weight, total, min_std)
    want = []
    for k, m in zip(*np.nonzero(valid), strict=True):
        c, r = int(k) * step, int(m) * step
        rows_j = np.arange(r, r + size) % second.shape[0]
        rows_i = (rows_j + shift[0]) % second.shape[0]
        pb, pa = second[rows_j, c:c + size], first[rows_i, c + shift[1]:c + shift[1] + size]
        if min(cv2.meanStdDev(pb)[1][0, 0], cv2.meanStdDev(pa)[1][0, 0]) < min_std:
            continue
        pa, pb = (p - np.float32(float(np.dot(weight.ravel(), p.ravel())) / total)
                  for p in (pa, pb))
        want.append((pa, pb, (r, c, int(rows_i[0]), c + shift[1])))
    assert 0 < len(want) < valid.sum()
    np.testing.assert_array_equal(a, np.array([w[0] for w in want]))
    np.testing.assert_array_equal(b, np.array([w[1] for w in want]))
    np.testing.assert_array_equal(where, np.array([w[2] for w in want]))


def test_polish_patches_polish_each_pair_as_polish_does() -> None:
    size = 32
    weight = cv2.createHanningWindow((size, size), cv2.CV_32F)
    first = np.stack([_textured((size, size)) for _ in range(4)])
    second = np.stack([np.roll(f, (1, 2), axis=(0, 1)) for f in first])
    starts = np.array([[2.0, 1.0], [1.7, 1.2], [np.nan, 0.0], [2.4, 0.6]])
    noise = np.tile([1e-3, -2e-3, 0.5, 0.4], (4, 1))
    for sums in (np.empty((0, 4)), noise):
        got = polish_patches(first, second, weight, starts, 3, sums, 0.1)
        for k in range(4):
            if not np.isfinite(starts[k]).all():
                np.testing.assert_array_equal(got[k], starts[k])
                continue
            moments = gradient_moments(first[k], weight)
            want = polish(first[k], second[k], weight, *starts[k], 3,
                          sums[k] if len(sums) else np.empty(0), *moments, 0.1)
            assert tuple(got[k]) == want
        if not len(sums):   # and the steps go to the true shift (2, 1)
            assert np.allclose(got[[0, 1, 3]], [2.0, 1.0], atol=0.05), got
