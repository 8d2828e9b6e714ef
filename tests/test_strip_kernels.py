"""The compiled kernels of unwrapping and registration against plain numpy/OpenCV.

Each kernel replaces a numpy or OpenCV expression for speed; here it is compared with
that expression (written out again, independently of the package) on random data,
bitwise where the kernel keeps the original's float32 arithmetic and to float
rounding where it accumulates in float64.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch._strip_kernels import (
    accumulate_strip,
    column_medians,
    cross_power_ccs,
    divide_by_reflectance,
    feathered_weight,
    gradient_moments,
    mask_strip,
    quantile_over_frames,
    residual_moments,
    ridge_peaks,
    scaled_uint8,
    shaded_albedo,
    shifted_residual_moments,
    upsample_masked,
)
from pipestitch.unwrap import local_contrast

RNG = np.random.default_rng(7)


def _bilinear(nodes: np.ndarray, step: int, n_rows: int, n_cols: int) -> np.ndarray:
    """Exact bilinear interpolation (float64) of (F, rows, cols) nodes every ``step``."""
    r = np.arange(n_rows) / step
    c = np.arange(n_cols) / step
    r0 = np.minimum(np.floor(r).astype(int), nodes.shape[1] - 2)
    c0 = np.minimum(np.floor(c).astype(int), nodes.shape[2] - 2)
    fr, fc = (r - r0)[:, None], (c - c0)[None, :]
    a = nodes.astype(float)
    return (a[:, r0][:, :, c0] * (1 - fr) * (1 - fc) + a[:, r0 + 1][:, :, c0] * fr * (1 - fc)
            + a[:, r0][:, :, c0 + 1] * (1 - fr) * fc + a[:, r0 + 1][:, :, c0 + 1] * fr * fc)


@pytest.mark.parametrize(("n_rows", "n_cols", "step"), [(37, 29, 4), (40, 33, 4), (21, 22, 3)])
def test_upsampled_maps_are_bilinear_and_masked_where_any_node_is_invalid(
        n_rows: int, n_cols: int, step: int) -> None:
    n_r, n_c = -(-(n_rows - 1) // step) + 1, -(-(n_cols - 1) // step) + 1
    nodes = (RNG.normal(size=(5, n_r, n_c)) * 100).astype(np.float32)
    nodes[2] = 1.0
    nodes[2, 3, 2] = 0.0                      # one invalid node
    out = upsample_masked(nodes, step, n_rows, n_cols, 0.999)
    ref = _bilinear(nodes, step, n_rows, n_cols)
    bad = ref[2] <= 0.999
    # Invalid: every output node the invalid node contributes to, and only those.
    rows, cols = np.nonzero(bad)
    assert rows.min() > (3 - 1) * step and rows.max() < (3 + 1) * step
    assert cols.min() > (2 - 1) * step and cols.max() < (2 + 1) * step
    for k, f in enumerate((0, 1, 3, 4)):
        fill = -1.0 if f < 2 else 0.0
        assert np.all(out[k][bad] == fill)
        # float32 arithmetic on values ~100: a few 1e-5 relative.
        np.testing.assert_allclose(out[k][~bad], ref[f][~bad], rtol=0, atol=1e-3)


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


def test_column_medians_are_numpy_nanmedians() -> None:
    values = RNG.random((60, 40)).astype(np.float32)
    values[RNG.random(values.shape) < 0.5] = np.nan
    values[:, 0] = np.nan                      # no data
    values[:55, 1] = np.nan                    # too little data (5 <= 6)
    values[:, 2] = 0.25                        # ties
    values[:51, 3] = np.nan                    # odd count (9), above the minimum
    counts = np.isfinite(values).sum(axis=0)
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        want = np.where(counts > 6, np.nanmedian(values, axis=0), np.nan)
    np.testing.assert_array_equal(column_medians(values, 6.0), want)


@pytest.mark.parametrize("n", [1, 2, 3, 6, 11, 12])
@pytest.mark.parametrize("q", [0.85, 0.5, 0.1])
def test_frame_quantiles_are_numpy_quantiles(n: int, q: float) -> None:
    stack = RNG.random((n, 9, 13)).astype(np.float32)
    stack[:, 0, 0] = 0.5                       # ties
    quant, med = quantile_over_frames(stack, n * q + (1 - q) - 1, True)
    np.testing.assert_array_equal(quant, np.quantile(stack, q, axis=0))
    np.testing.assert_array_equal(med, np.median(stack, axis=0))


def test_ridge_peaks_are_the_strongest_local_maxima() -> None:
    ridge = RNG.random((50, 80)).astype(np.float32)
    index, value = ridge_peaks(ridge, 0.3, 3)
    for row, idx, val in zip(ridge, index, value, strict=True):
        j = np.arange(2, row.size - 2)
        peak = j[(row[j] > 0.3) & (row[j] > row[j - 1]) & (row[j] >= row[j + 1])]
        best = peak[np.argsort(-row[peak], kind="stable")][:3]
        assert list(idx[:best.size]) == list(best)
        np.testing.assert_array_equal(val[:best.size], row[best])
        assert np.all(np.isneginf(val[best.size:]))


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

def test_strip_mask_uses_the_nearest_pixel_as_cv2_remap_does() -> None:
    occluded = RNG.random((20, 30)) < 0.3
    # Half-integer coordinates (rounded to even), out of the frame, and invisible nodes.
    map_x = (RNG.integers(-4, 66, (15, 17)) / 2).astype(np.float32)
    map_y = (RNG.integers(-4, 46, (15, 17)) / 2).astype(np.float32)
    map_x[0, :3] = -1
    values = RNG.random(map_x.shape).astype(np.float32)
    values[1, :2] = np.nan
    quality = RNG.random(map_x.shape).astype(np.float32)
    hidden = cv2.remap(occluded.astype(np.uint8), map_x, map_y, cv2.INTER_NEAREST,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=1).astype(bool)
    bad = ~np.isfinite(values) | (quality < 0.4) | hidden | (map_x < 0)
    got = values.copy()
    weight = mask_strip(got, map_x, map_y, quality, 0.4, occluded)
    np.testing.assert_array_equal(np.isnan(got), bad)
    np.testing.assert_array_equal(weight, np.where(bad, 0, quality))
    got = values.copy()   # no occluder mask: only invisible, missing and poor nodes
    mask_strip(got, map_x, map_y, quality, 0.4, np.zeros((0, 0), bool))
    np.testing.assert_array_equal(np.isnan(got),
                                  (map_x < 0) | ~np.isfinite(values) | (quality < 0.4))


def test_local_contrast_is_value_over_local_mean() -> None:
    values = (0.5 + RNG.random((40, 50))).astype(np.float32)
    values[5:9, 10:20] = np.nan
    contrast, support = local_contrast(values, 3.0)
    valid = np.isfinite(values)
    filled = np.where(valid, values, 0).astype(np.float32)
    blur = [cv2.GaussianBlur(a, (0, 0), 3.0, borderType=cv2.BORDER_REFLECT)
            for a in (valid.astype(np.float32), filled)]
    local = blur[1] / np.maximum(blur[0], np.float32(1e-6))
    want = np.where(valid, filled / np.maximum(local, np.float32(1e-6)) - 1, 0)
    np.testing.assert_array_equal(contrast, want.astype(np.float32))
    np.testing.assert_array_equal(support, blur[0])


def test_reflectance_division_is_the_numpy_expression() -> None:
    polar, local, broad = (RNG.random((30, 40)).astype(np.float32) for _ in range(3))
    broad[0, :5] = 0
    valid = (local > 0.15 * broad) & (broad > 0)
    relative = np.where(valid, local / np.where(broad > 0, broad, 1.0), 1.0)
    want = np.where(valid, polar / np.maximum(relative, 0.15), 0.0).astype(np.float32)
    np.testing.assert_array_equal(divide_by_reflectance(polar, local, broad, 0.15, 0.15), want)


def test_shaded_albedo_is_the_numpy_division_with_its_validity() -> None:
    values = RNG.random((30, 40)).astype(np.float32)
    values[2, :7] = np.nan
    shading = RNG.random((30, 40)).astype(np.float32)
    shading[3, :4] = 0   # below the 1e-6 floor
    weight = np.where(RNG.random((30, 40)) < 0.2, 0, RNG.random((30, 40))).astype(np.float32)
    level = 0.5 + RNG.random(40)
    want = values / np.maximum(shading * level[None, :], 1e-6)   # float64, as numpy promotes
    valid = np.isfinite(want) & (weight > 0)
    albedo, got_valid = shaded_albedo(values, shading, level, weight)
    np.testing.assert_array_equal(got_valid.astype(bool), valid)
    np.testing.assert_array_equal(albedo, np.where(valid, want, 0).astype(np.float32))
    feather = RNG.random((30, 40)).astype(np.float32)
    np.testing.assert_array_equal(feathered_weight(weight, feather, got_valid),
                                  np.where(valid, weight * feather, 0).astype(np.float32))


def test_accumulated_strip_is_the_numpy_sums_over_its_columns() -> None:
    total = RNG.random((12, 50)).astype(np.float32)
    weights = RNG.random((12, 50)).astype(np.float32)
    albedo = RNG.random((12, 20)).astype(np.float32)
    weight = np.where(RNG.random((12, 20)) < 0.3, 0, RNG.random((12, 20))).astype(np.float32)
    want_total, want_weights = total.copy(), weights.copy()
    want_total[:, 7:27] += albedo.astype(np.float64) * 1.3 * weight
    want_weights[:, 7:27] += weight
    accumulate_strip(total, weights, 7, albedo, weight, 1.3)
    np.testing.assert_array_equal(weights, want_weights)
    np.testing.assert_allclose(total, want_total, rtol=1e-7, atol=0)


def test_scaled_uint8_is_the_numpy_conversion() -> None:
    image = (3 * RNG.random((40, 50))).astype(np.float32)
    image[3, :9] = np.nan
    image[4, :3] = np.inf
    image[5, :4] = 0   # data, mapped to 1
    finite = np.isfinite(image)
    want = np.zeros(image.shape, np.uint8)
    want[finite] = np.clip(np.rint(image[finite] / 1.7 * 250), 1, 255).astype(np.uint8)
    np.testing.assert_array_equal(scaled_uint8(image, 1.7), want)
