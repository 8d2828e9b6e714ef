"""The LED frames' noise model, and the noise it leaves in a strip's local contrast.

Ground truth: frames drawn here with a known noise variance per signal level, and white
noise resampled with OpenCV's bilinear remap (what the unwrap does) many times over.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from pipestitch.mosaic.noise import (
    ContrastNoise,
    NoiseModel,
    contrast_noise,
    estimate_noise,
    patch_noise,
    patch_noise_sums,
    patch_table,
)

OFFSET, SLOPE = 2.5e-5, 1.2e-4   # read noise and quantisation; shot noise (full scale 1)


def _frame(rng: np.random.Generator, shape=(512, 640)) -> np.ndarray:
    """LED-like shading (bright centre, dark corners, clipped in the middle), a weak
    texture, and noise of variance OFFSET + SLOPE * signal."""
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    r = np.hypot(rows - shape[0] / 2, cols - shape[1] / 2) / (0.5 * max(shape))
    texture = cv2.GaussianBlur(rng.standard_normal(shape), (0, 0), 2.0)
    signal = np.clip(1.1 * np.exp(-1.5 * r * r), 0, 1) * (1 + 0.01 * texture / texture.std())
    noisy = signal + np.sqrt(OFFSET + SLOPE * signal) * rng.standard_normal(shape)
    return np.clip(noisy, 0, 1).astype(np.float32)


def test_noise_model_is_measured_from_the_frames() -> None:
    rng = np.random.default_rng(0)
    model = estimate_noise([_frame(rng) for _ in range(3)])
    assert model is not None
    levels = np.array([0.1, 0.3, 0.6, 0.9])
    truth = OFFSET + SLOPE * levels
    # a tenth of the blocks at each level, 16 x 16 px each: ~5 % per level
    assert model.variance(levels) == pytest.approx(truth, rel=0.12)


def test_too_little_to_measure_gives_no_model() -> None:
    assert estimate_noise([]) is None
    assert estimate_noise([np.full((30, 30), 0.5, np.float32)]) is None   # under 3 blocks
    assert estimate_noise([np.ones((256, 256), np.float32)]) is None      # all clipped


def _upsampling_maps(n_rows: int = 64, n_cols: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Strip nodes drawn 0.4 (first column) to 1.0 (last) frame pixels apart along the
    columns and 0.537 apart along the rows (every sampling phase): the far end of a strip,
    upsampled."""
    step = 0.4 + 0.6 * np.arange(n_cols) / (n_cols - 1)
    x = 8.0 + np.concatenate([[0.0], np.cumsum(step[:-1])])
    map_x = np.repeat(x[None, :], n_rows, 0).astype(np.float32)
    map_y = np.repeat((8.0 + 0.537 * np.arange(n_rows))[:, None], n_cols, 1).astype(np.float32)
    return map_x, map_y


def test_noise_fields_match_remapped_white_noise() -> None:
    """What the template's noise adds to a patch's Lucas-Kanade sums, from the model,
    against the same sums over 400 draws of white noise remapped by OpenCV."""
    map_x, map_y = _upsampling_maps()
    level, variance = 0.5, 4e-5
    window = cv2.createHanningWindow((64, 64), cv2.CV_32F)
    rng = np.random.default_rng(1)
    d_x, h_x, h_y = [], [], []
    for _ in range(400):
        noise = rng.standard_normal((48, 80)).astype(np.float32) * np.float32(np.sqrt(variance))
        n = cv2.remap(noise, map_x, map_y, cv2.INTER_LINEAR).astype(np.float64) / level
        gy, gx = np.gradient(n)
        d_x.append(float((window * gx * n).sum()))
        h_x.append(float((window * gx * gx).sum()))
        h_y.append(float((window * gy * gy).sum()))
    fields = contrast_noise(map_x, map_y, np.full(map_x.shape, level, np.float32),
                            NoiseModel(variance, 0.0))
    sums = patch_noise(patch_table(fields, window), fields.step, 0, 0)
    # the strip's own table: the same, computed once per window and kept
    kept = fields.patch_table(window)
    np.testing.assert_array_equal(kept, patch_table(fields, window))
    assert fields.patch_table(window.copy()) is kept
    assert fields.patch_table(window[:32, :32].copy()) is not kept
    # many patches at once: each row the patch's own sums (rows wrap, columns clip)
    rows, cols = np.array([0, 7, 30, 47, 95]), np.array([0, 13, 40, 79, 500])
    many = patch_noise_sums(kept, fields.step, rows, cols)
    assert many.shape == (5, 4) and many.flags.c_contiguous
    for (r, c), got in zip(zip(rows, cols, strict=True), many, strict=True):
        assert tuple(got) == dataclasses.astuple(patch_noise(kept, fields.step, r, c))
    # Monte-Carlo error of the mean ~2 %; the model's phase average and its every-4th-node
    # fields add a few per cent
    assert sums.d_x == pytest.approx(np.mean(d_x), rel=0.15)
    assert sums.h_x == pytest.approx(np.mean(h_x), rel=0.1)
    assert sums.h_y == pytest.approx(np.mean(h_y), rel=0.1)
    # the correlation grows towards the upsampled end: E[g n] along the rows, whose
    # step does not change, is zero
    assert abs(sums.d_y) < 0.05 * abs(sums.d_x)


def _bspline(u: np.ndarray) -> np.ndarray:
    """The cubic B-spline: phase-averaged correlation of linearly interpolated white noise."""
    u = np.minimum(np.abs(u), 2.0)
    far = 2.0 - u
    return np.where(u <= 1.0, 2.0 / 3.0 - u * u * (1.0 - 0.5 * u), far * far * far / 6.0)


def _numpy_fields(map_x: np.ndarray, map_y: np.ndarray, local_mean: np.ndarray,
                  model: NoiseModel, step: int) -> np.ndarray:
    """The noise fields as numpy expressions: what the compiled loop replaces."""
    mx = map_x[::step, ::step].astype(np.float64)
    my = map_y[::step, ::step].astype(np.float64)
    mean = np.maximum(local_mean[::step, ::step].astype(np.float64), 1e-6)
    relative = model.variance(mean) / (mean * mean)
    variance = relative * _bspline(np.float64(0.0)) ** 2
    d, g = [], []
    for axis in (0, 1):
        if mx.shape[axis] < 2:
            d.append(np.zeros_like(mx))
            g.append(np.zeros_like(mx))
            continue
        dx = np.gradient(mx, axis=axis) / step
        dy = np.gradient(my, axis=axis) / step
        lag1 = relative * _bspline(dx) * _bspline(dy)
        lag2 = relative * _bspline(2 * dx) * _bspline(2 * dy)
        d.append(0.5 * np.gradient(lag1, axis=axis) / step)
        g.append(0.5 * (variance - lag2))
    return np.stack([d[1], d[0], g[1], g[0]]).astype(np.float32)


@pytest.mark.parametrize("shape", [(37, 53), (1, 9), (9, 1), (4, 4)])
def test_compiled_fields_are_the_numpy_expressions(shape: tuple[int, int]) -> None:
    """The compiled noise fields equal the numpy expressions they replace, bitwise, on
    maps that stretch and shear (rows and columns of any count, one included)."""
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    map_x = (cols * (0.3 + 0.02 * rows) + rng.uniform(-0.1, 0.1, shape)).astype(np.float32)
    map_y = (rows * 0.7 + 0.1 * cols ** 1.5).astype(np.float32)
    mean = rng.uniform(0.0, 1.0, shape).astype(np.float32)   # zeros too: the 1e-6 floor
    mean[0, 0] = 0.0
    model = NoiseModel(2e-5, 1.1e-4)
    for step in (1, 2, 4):
        fields = contrast_noise(map_x, map_y, mean, model, step)
        assert isinstance(fields, ContrastNoise) and fields.step == step
        expected = _numpy_fields(map_x, map_y, mean, model, step)
        assert fields.fields.shape == expected.shape and fields.fields.dtype == np.float32
        np.testing.assert_array_equal(fields.fields, expected)
