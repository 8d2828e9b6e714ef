"""The compiled laser-ring kernels against the numpy expressions they replace."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.pose._ring_kernels import (
    _percentile_20,
    _window_sum,
    centroids,
    flatten_by_moved_reflectance,
    flatten_by_reflectance,
    line_widths,
    ridge_peaks,
)
from pipestitch.pose.pair_motion import LedShift

RNG = np.random.default_rng(7)


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


@pytest.mark.parametrize("shape", [(30, 40), (9, 200), (1, 7), (13, 1)])
@pytest.mark.parametrize("box", [3, 41, 81])
def test_reflectance_division_is_opencvs_blurs_and_the_numpy_expression(
        shape: tuple[int, int], box: int) -> None:
    """Row counts that are not a multiple of the kernel's block, boxes longer than a
    row, a dark patch and zeros: the same float32 values, to the bit (the float64
    sums of float32 samples are exact here whatever their order)."""
    polar, local = (RNG.random(shape).astype(np.float32) for _ in range(2))
    local[: shape[0] // 2, : shape[1] // 3] *= 0.05
    local[-1, :2] = 0
    kernel = (box, 1)
    broad = cv2.blur(cv2.blur(local, kernel, borderType=cv2.BORDER_REPLICATE), kernel,
                     borderType=cv2.BORDER_REPLICATE)
    valid = (local > 0.15 * broad) & (broad > 0)
    relative = np.where(valid, local / np.where(broad > 0, broad, 1.0), 1.0)
    want = np.where(valid, polar / np.maximum(relative, 0.15), 0.0).astype(np.float32)
    got = flatten_by_reflectance(polar, local, box, 0.15, 0.15)
    np.testing.assert_array_equal(got, want)
    assert np.any(got == 0) and np.any(got != 0)


def _moved_frames(n_rays: int = 37, n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    polar, local = (RNG.random((n_rays, n)).astype(np.float32) + 0.05 for _ in range(2))
    local[: n_rays // 3, : n // 4] *= 0.05   # a dark patch: zeros in the division
    return polar, local


@pytest.mark.parametrize(("along", "across"), [(7.0, -2.0), (-45.0, 3.0), (20.0, -30.0),
                                               (0.0, 0.0)])
def test_moved_division_is_the_division_by_the_moved_frame_at_whole_shifts(
        along: float, across: float) -> None:
    """Whole shifts, out past a row's end and in past its start (most of a row), before
    the first row and past the last (rows wrap): the LED frame moved by
    ``LedShift.apply`` (OpenCV's remap, exact at whole shifts) and divided, to the bit."""
    polar, local = _moved_frames()
    shift = LedShift.constant(polar.shape[0], along, across)
    want = flatten_by_reflectance(polar, shift.apply(local), 41, 0.15, 0.15)
    got = flatten_by_moved_reflectance(polar, local, shift.along, shift.across, 41, 0.15,
                                       0.15)
    np.testing.assert_array_equal(got, want)
    assert np.any(got != 0)


def test_moved_division_interpolates_a_shift_varying_along_the_ring() -> None:
    """Fractional shifts, different on every ray, inward and outward, the last rays
    reading past the last row (they wrap): the moved frame linearly interpolated in both
    directions (here in float64: the kernel's float32 agrees to 1e-5), and within
    OpenCV's remap, which rounds each weight to 1/32 of a sample."""
    polar, local = _moved_frames()
    n_rays, n = local.shape
    phi = np.arange(n_rays) * (2 * np.pi / n_rays)
    shift = LedShift(-1.3 + 6.6 * np.cos(phi), 1.7 * np.sin(phi) + 0.4)
    rows = np.arange(n_rays) + shift.across
    low = np.floor(rows).astype(int)
    cols = np.clip(np.arange(n)[None, :] + shift.along[:, None], 0, n - 1)
    left = np.floor(cols).astype(int)
    right = np.minimum(left + 1, n - 1)
    wx, wy = cols - left, (rows - low)[:, None]

    def along_row(r: np.ndarray) -> np.ndarray:
        row = local.astype(np.float64)[r % n_rays]
        return (1 - wx) * np.take_along_axis(row, left, 1) + wx * np.take_along_axis(row,
                                                                                      right, 1)

    moved = ((1 - wy) * along_row(low) + wy * along_row(low + 1)).astype(np.float32)
    got = flatten_by_moved_reflectance(polar, local, shift.along, shift.across, 41, 0.15,
                                       0.15)
    want = flatten_by_reflectance(polar, moved, 41, 0.15, 0.15)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    by_remap = flatten_by_reflectance(polar, shift.apply(local), 41, 0.15, 0.15)
    assert 0 < np.max(np.abs(got - by_remap)) < 0.05 * np.max(np.abs(want))
    assert np.any(got == 0) and np.any(got != 0)


def _moved_in_float32(local: np.ndarray, along: np.ndarray, across: np.ndarray) -> np.ndarray:
    """The moved LED frame as the kernel forms each sample, in numpy's float32: the two
    rows about ``r + across[r]`` (wrapping), each read at its columns ``j + floor(along)``
    and the next, clamped to the row, then weighted along and across the rays."""
    n_rays, n = local.shape
    f32 = np.float32
    out = np.empty_like(local)
    for r in range(n_rays):
        low, first = np.floor(r + across[r]), np.floor(along[r])
        wy, wx = f32(r + across[r] - low), f32(along[r] - first)
        above, below = local[int(low) % n_rays], local[(int(low) + 1) % n_rays]
        c0 = np.clip(np.arange(n) + int(first), 0, n - 1)
        c1 = np.clip(np.arange(n) + int(first) + 1, 0, n - 1)
        top = (f32(1) - wx) * above[c0] + wx * above[c1]
        bottom = (f32(1) - wx) * below[c0] + wx * below[c1]
        out[r] = (f32(1) - wy) * top + wy * bottom
    return out


def test_moved_division_reads_every_sample_as_its_clamped_formula() -> None:
    """Fractional shifts from far in past a row's start to far out past its end (every
    sample clamped), through every split between the samples read inside the row and
    those clamped at either end: the same float32 values as the per-sample formula with
    clamped columns, to the bit."""
    polar, local = _moved_frames(n_rays=41, n=50)
    n_rays, n = local.shape
    along = np.linspace(-1.5 * n, 1.5 * n, n_rays) + 0.37
    along[::7] = np.floor(along[::7])               # whole shifts too
    along[3], along[4] = n - 1.25, -(n - 1) + 0.25  # one sample inside, at either end
    across = np.sin(np.arange(n_rays)) * 3.4
    got = flatten_by_moved_reflectance(polar, local, along, across, 41, 0.15, 0.15)
    want = flatten_by_reflectance(polar, _moved_in_float32(local, along, across), 41, 0.15,
                                  0.15)
    np.testing.assert_array_equal(got, want)
    assert np.any(got != 0)


# --- the line's width and the centroids: the numpy expressions they replace -------------

def _row_percentile(values: np.ndarray, q: float) -> np.ndarray:
    ordered = np.sort(values, axis=1)          # NaN last
    n = np.count_nonzero(np.isfinite(values), axis=1)
    pos = np.maximum(n - 1, 0) * (q / 100.0)
    lo = np.floor(pos).astype(np.intp)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    rows = np.arange(len(values))
    frac = pos - lo
    out = ordered[rows, lo] * (1.0 - frac) + ordered[rows, hi] * frac
    return np.where(n > 0, out, np.nan)


def _crossing(profile: np.ndarray, below: np.ndarray, level: np.ndarray) -> np.ndarray:
    first = np.argmax(below, axis=1)
    found = below[np.arange(len(first)), first] & (first > 0)
    first = np.where(found, first, 1)
    rows = np.arange(len(first))
    hi, lo = profile[rows, first - 1], profile[rows, first]
    frac = np.where(hi > lo, (hi - level[:, 0]) / np.where(hi > lo, hi - lo, 1), 0.5)
    return np.where(found, first - 1 + np.clip(np.nan_to_num(frac, nan=0.5), 0, 1), np.nan)


def _numpy_line_widths(polar: np.ndarray, rows: np.ndarray, idx: np.ndarray,
                       half: int) -> np.ndarray:
    offsets = np.arange(-half, half + 1)
    cols = idx[:, None] + offsets[None, :]
    inside = (cols >= 0) & (cols < polar.shape[1])
    profile = np.where(inside, polar[rows[:, None], np.clip(cols, 0, polar.shape[1] - 1)],
                       np.nan)
    base = _row_percentile(profile, 20.0)
    peak = np.nanmax(profile[:, half - 2:half + 3], axis=1)
    level = (base + (peak - base) / 2)[:, None]
    below = ~(profile >= level)
    fwhm = (_crossing(profile[:, half::-1], below[:, half::-1], level)
            + _crossing(profile[:, half:], below[:, half:], level))
    return np.where(np.isfinite(fwhm) & (peak > base), fwhm, np.nan)


def _numpy_centroids(polar: np.ndarray, smooth: np.ndarray, rows: np.ndarray, idx: np.ndarray,
                     half: int, reach: np.ndarray) -> np.ndarray:
    offsets = np.arange(-half, half + 1)
    cols = np.clip(idx[:, None] + offsets[None, :], 0, polar.shape[1] - 1)
    profile = polar[rows[:, None], cols]
    base = np.minimum(profile[:, :1], profile[:, -1:])
    peak = smooth[rows, idx][:, None]
    weight = np.clip(profile - (base + 0.3 * (peak - base)), 0, None)
    weight *= np.abs(offsets)[None, :] <= np.maximum(reach, 2)[:, None]
    total = weight.sum(axis=1)
    shift = np.where(total > 0, (weight * offsets).sum(axis=1) / np.where(total > 0, total, 1), 0)
    return idx + shift


def _polar_lines(n_rows: int, n_cols: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays with a Gaussian line each (widths 0.8-12 samples, some saturated, some by a
    ray's end), a sloping background and noise; (polar, rows, idx of the brightest)."""
    cols = np.arange(n_cols)
    centre = RNG.uniform(-3, n_cols + 3, n_rows)
    width = RNG.uniform(0.8, 12, n_rows)
    height = RNG.uniform(0.05, 2.0, n_rows)
    polar = (height[:, None] * np.exp(-0.5 * ((cols - centre[:, None]) / width[:, None]) ** 2)
             + RNG.uniform(0, 0.3, n_rows)[:, None] * cols / n_cols
             + RNG.normal(0, 0.02, (n_rows, n_cols))).astype(np.float32)
    polar[::7] = np.minimum(polar[::7], np.float32(0.6))    # flat tops
    polar[5, :] = 0.25                                      # a ray without a line
    rows = np.repeat(np.arange(n_rows), 2)
    idx = np.clip(np.repeat(np.rint(centre).astype(np.int64), 2)
                  + RNG.integers(-3, 4, 2 * n_rows), 0, n_cols - 1)
    idx[1::2] = RNG.integers(0, n_cols, n_rows)             # other candidates anywhere
    return polar, rows, idx


@pytest.mark.parametrize("half", [4, 16, 40])
def test_line_widths_are_the_numpy_expressions(half: int) -> None:
    """Windows past either end of a ray, centres below half maximum, flat tops, flat
    rays: the same widths to the bit, NaN in the same places."""
    polar, rows, idx = _polar_lines(600, 150)
    got = line_widths(polar, rows, idx, half)
    want = _numpy_line_widths(polar, rows, idx, half)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got).any() and np.isfinite(got).sum() > len(got) // 3


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_window_sums_are_numpys_sums(dtype: type) -> None:
    """Sequential below 8 values, then 8 partial sums: the same sum as numpy's to the
    bit, at every size up to numpy's 128-value block."""
    for n in range(1, 129):
        values = (RNG.standard_normal(n) * 10.0 ** RNG.uniform(-3, 3)).astype(dtype)
        assert _window_sum(values, dtype(0)) == values.sum(), n


@pytest.mark.parametrize("half", [2, 6, 15])
def test_centroids_are_the_numpy_expressions(half: int) -> None:
    """Windows clamped at a ray's ends, cut by each candidate's reach (none, 0, a few
    samples, NaN: no sample), rays without weight: the same positions to the bit."""
    polar, rows, idx = _polar_lines(600, 150)
    smooth = cv2.GaussianBlur(polar, (0, 0), 1.5)
    reach = RNG.choice([np.inf, 0.0, 1.0, 3.0, 7.0, np.nan], len(idx))
    got = centroids(polar, smooth, rows, idx, half, reach)
    np.testing.assert_array_equal(got, _numpy_centroids(polar, smooth, rows, idx, half, reach))
    assert np.any(got != idx) and np.any(got == idx)


def test_percentile_of_a_window_is_the_sorted_rows_interpolation() -> None:
    """NaN left out, infinities sorted among the values, rows of 0, 1 and 2 values."""
    values = RNG.normal(size=(300, 41)).astype(np.float32)
    values[RNG.random(values.shape) < 0.2] = np.nan
    values[3] = np.nan
    values[4, 1:] = np.nan
    values[5, 2:] = np.nan
    values[6, :3] = [-np.inf, np.inf, -np.inf]
    want = _row_percentile(values, 20.0)
    scratch = np.empty(41, np.float32)
    got = [_percentile_20(row, int(np.isfinite(row).sum()), scratch) for row in values]
    np.testing.assert_array_equal(got, want)
