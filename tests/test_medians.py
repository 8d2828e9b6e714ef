"""pipestitch.imaging.medians: numpy's medians, to the bit and of numpy's type."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pipestitch.imaging import mad_sigma, median, nanmedian
from pipestitch.imaging.medians import _middle_ranks

FLOATS = st.sampled_from([np.float32, np.float64])


def _same(got: object, want: object) -> bool:
    return type(got) is type(want) and (got == want or (np.isnan(got) and np.isnan(want)))


@settings(max_examples=300, deadline=None)
@given(FLOATS.flatmap(lambda dtype: hnp.arrays(
    dtype, hnp.array_shapes(min_dims=1, max_dims=3, min_side=1, max_side=9),
    elements=st.one_of(st.floats(-2.0**100, 2.0**100, width=32), st.just(float("nan"))))))
def test_median_and_nanmedian_are_numpys(values: np.ndarray) -> None:
    """Any shape, odd and even sizes, ties, signed zeros, NaN anywhere."""
    assert _same(median(values), np.median(values))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # numpy's all-NaN warning
        want = np.nanmedian(values)
    assert _same(nanmedian(values), want)


@pytest.mark.parametrize("size", [92_640, 140_160, 140_161])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_large_arrays_as_the_ring_noise_takes_them(size: int, dtype: type) -> None:
    """The sizes the hot callers see (a strided 2-D sample), against numpy's MAD."""
    values = (np.random.default_rng(size).standard_normal(size) * 0.01).astype(dtype)
    sample = values.reshape(-1, 5)[:, ::2] if size % 5 == 0 else values
    assert _same(median(sample), np.median(sample))
    want = 1.4826 * float(np.median(np.abs(sample - np.median(sample))))
    assert mad_sigma(sample) == want


def test_other_dtypes_and_empty_arrays_are_left_to_numpy() -> None:
    ints = np.array([3, 1, 4, 1, 5, 9], np.int64)
    assert _same(median(ints), np.median(ints))
    assert np.isnan(mad_sigma(np.array([], np.float32)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert _same(median(np.array([], np.float64)), np.median(np.array([], np.float64)))
    assert np.isnan(nanmedian(np.full(4, np.nan, np.float32)))


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float32, st.integers(1, 3000), elements=st.one_of(
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-30, -3e38, float("inf"), float("-inf")]),
    st.floats(-1e6, 1e6, width=32), st.just(float("nan")))))
def test_float32_selection_is_numpys_with_ties_zeros_infinities_and_nan(
        values: np.ndarray) -> None:
    """The radix selection's float32 path: many ties, both zeros (where numpy's own
    partition decides), infinities, values across all exponents, NaN anywhere."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # numpy's overflow, all-NaN
        assert _same(median(values), np.median(values))
        assert _same(nanmedian(values), np.nanmedian(values))


@pytest.mark.parametrize("seed", range(6))
def test_middle_ranks_are_the_sorted_values(seed: int) -> None:
    """Ranks count // 2 - 1 and count // 2 of the sorted non-NaN values, whichever of
    the key's digits separates them (far apart, one ulp apart, equal)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 200_000))
    values = (rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30)).astype(np.float32)
    values[rng.integers(0, n, n // 10)] = np.nan
    if seed % 2:   # values one ulp apart about the middle
        ulp = np.spacing(np.float32(1.5))
        values = np.where(np.isnan(values), values,
                          np.float32(1.5) + np.sign(values) * ulp).astype(np.float32)
    kept = np.sort(values[~np.isnan(values)])
    middle, count = _middle_ranks(values, True)
    assert count == kept.size
    assert middle[1] == kept[count // 2] and middle[0] == kept[count // 2 - 1]
    assert _middle_ranks(values, False)[1] == -1


def test_read_only_and_strided_float32_arrays() -> None:
    """As the frame cache shares frames and the ring's noise samples them."""
    values = np.random.default_rng(3).standard_normal((300, 302)).astype(np.float32)
    values.flags.writeable = False
    for sample in (values, values[::3, ::3]):
        assert _same(median(sample), np.median(sample))
        assert mad_sigma(sample) == 1.4826 * float(np.median(np.abs(sample - np.median(sample))))
