"""The compiled blending kernels against the numpy expressions they replace."""

from __future__ import annotations

import numpy as np

from pipestitch.mosaic._blend_kernels import (
    accumulate_strip,
    feathered_weight,
    gain_ratios,
    shaded_albedo,
)

RNG = np.random.default_rng(7)


def test_shaded_albedo_is_the_numpy_division_with_its_validity() -> None:
    values = RNG.random((30, 40)).astype(np.float32)
    values[2, :7] = np.nan
    shading = RNG.random((30, 40)).astype(np.float32)
    shading[3, :4] = 0   # below the 1e-6 floor
    weight = np.where(RNG.random((30, 40)) < 0.2, 0, RNG.random((30, 40))).astype(np.float32)
    want = values / np.maximum(shading.astype(np.float64), 1e-6)   # in float64
    valid = np.isfinite(want) & (weight > 0)
    albedo, got_valid = shaded_albedo(values, shading, weight)
    np.testing.assert_array_equal(got_valid.astype(bool), valid)
    np.testing.assert_array_equal(albedo, np.where(valid, want, 0).astype(np.float32))
    # the feather from the wrapped, padded strip's edge distances (4 rows, 1 column)
    distance = (RNG.random((38, 42)) * 9).astype(np.float32)
    feather = np.clip(distance[4:-4, 1:-1] / 4, 0, 1).astype(np.float32)
    assert np.any(feather == 1) and np.any((feather > 0) & (feather < 1))
    np.testing.assert_array_equal(feathered_weight(weight, distance, got_valid, 4),
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


def test_gain_ratios_are_the_numpy_expression_over_the_strided_overlap() -> None:
    """The exposure gain's node ratios (blend.Canvas._gain): the same float32 values in
    the same order as numpy's masked expression, thresholds met exactly included (a
    float32 compared with a Python float is compared in float32)."""
    total = RNG.random((31, 60)).astype(np.float32)
    weights = RNG.random((31, 60)).astype(np.float32) * 1.2
    albedo = RNG.random((31, 25)).astype(np.float32)
    weight = RNG.random((31, 25)).astype(np.float32)
    # values at and one float32 step beside each threshold, on the nodes read
    for field, level in ((weight, 0.2), (albedo, 1e-6)):
        at = np.float32(level)
        field[0, :6:2] = [np.nextafter(at, np.float32(0)), at, np.nextafter(at, np.float32(1))]
    weights[2, 9:15:2] = [np.nextafter(np.float32(0.5), np.float32(0)), 0.5, 0.5000001]
    albedo[4, :4] = 0
    for stride, col0 in ((2, 9), (1, 0), (3, 35)):
        cols = slice(col0, col0 + albedo.shape[1])
        have, mine = weights[::stride, cols][:, ::stride], albedo[::stride, ::stride]
        both = (weight[::stride, ::stride] > 0.2) & (have > 0.5) & (mine > 1e-6)
        want = total[::stride, cols][:, ::stride][both] / (have[both] * mine[both])
        out = np.full(albedo.size, np.nan, np.float32)
        found = gain_ratios(total, weights, col0, albedo, weight, stride, out)
        assert found == np.count_nonzero(both)
        np.testing.assert_array_equal(out[:found], want)
