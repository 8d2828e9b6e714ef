"""The occluder mask: what stays fixed in the image is masked, what moves with the wall is not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.mosaic.occluders import full_scale, noise_variance, occluder_mask, static_pixels


def test_occluder_mask_keeps_static_dark_and_drops_moving_dark() -> None:
    rng = np.random.default_rng(0)
    frames = []
    for k in range(7):
        f = (0.5 + 0.2 * cv2.GaussianBlur(rng.random((200, 240)), (0, 0), 2)).astype(np.float32)
        f[:, 100:110] = 0.02                     # the arm: always there
        cv2.circle(f, (30 + 25 * k, 50), 6, 0.02, -1)   # a hole moving with the wall
        frames.append(f)
    mask = occluder_mask(frames)
    assert mask[:, 102:108].all()
    assert not mask[50, 30] and not mask[50, 130]
    assert mask.mean() < 0.15
    # the frames spread over threads give the same mask
    np.testing.assert_array_equal(occluder_mask(frames, workers=3), mask)
    with pytest.raises(ValueError):
        occluder_mask([])
    with pytest.raises(ValueError, match="one size"):
        occluder_mask([frames[0], frames[1][:, :200]])


@pytest.mark.parametrize("level", [0.02, 0.3, 0.9])
def test_a_static_occluder_of_any_brightness_is_masked(level: float) -> None:
    """A bar that never moves is masked whether it is darker or brighter than the wall
    (a lit metal arm); the wall, textured and shaded differently in every frame, is not."""
    rng = np.random.default_rng(1)
    frames = []
    for k in range(9):
        wall = cv2.GaussianBlur(rng.random((200, 240)), (0, 0), 2)
        shade = 0.9 + 0.1 * np.sin(k)          # the probe's offset changes the lighting
        f = (0.35 + 0.25 * wall) * shade
        f[:, 100:116] = level                  # the arm: fixed in the image
        noise = rng.normal(0, 0.004, f.shape)  # the sensor's noise, in every pixel
        frames.append(np.clip(f + noise, 0, 1).astype(np.float32))
    mask = occluder_mask(frames)
    assert mask[:, 104:112].mean() > 0.99
    wall = np.ones(mask.shape, bool)
    wall[:, 90:126] = False                    # the arm and its dilated edges aside
    assert mask[wall].mean() < 0.01


def test_a_wall_as_noisy_as_it_is_textured_is_not_static() -> None:
    """Sensor noise as strong as the wall's texture: each pixel of the wall varies over
    the frames little more than the noise does, but its neighbourhood's mean varies with
    the texture (correlated over pixels) while the noise averages out: not static. The
    fixed bar still is."""
    rng = np.random.default_rng(5)
    stack = []
    for _ in range(11):
        wall = cv2.GaussianBlur(rng.standard_normal((200, 240)), (0, 0), 3)
        f = 0.33 + 0.05 * wall / wall.std()            # texture sd 0.05
        f[:, 100:116] = 0.2                           # the fixed bar
        stack.append(np.clip(f + rng.normal(0, 0.05, f.shape), 0, 1))   # noise sd 0.05
    stack = np.array(stack, np.float32)
    static = static_pixels(stack, np.median(stack, axis=0))
    assert static[:, 104:112].mean() > 0.99
    wall = np.ones(static.shape, bool)
    wall[:, 96:120] = False
    assert static[wall].mean() < 0.03   # 1.1 %; on each pixel's variance alone: 99 %


def test_static_pixels_need_the_noise_not_a_constant() -> None:
    """The same static bar under 10x the noise is still static (the noise is measured),
    and a saturated wall is not taken for an occluder."""
    rng = np.random.default_rng(2)
    stack = []
    for k in range(9):
        f = 0.3 + 0.3 * cv2.GaussianBlur(rng.random((120, 160)), (0, 0), 2) * (1 + 0.1 * k)
        f[:, 60:80] = 0.5
        f[:20] = 1.0                           # saturated in every frame
        stack.append(f + rng.normal(0, 0.02, f.shape) * (f < 1.0))
    stack = np.clip(np.stack(stack), 0, 1).astype(np.float32)
    static = static_pixels(stack, np.median(stack, axis=0))
    assert static[30:, 64:76].mean() > 0.99
    assert not static[:20].any()
    assert static[30:, :50].mean() < 0.01


def test_noise_variance_is_the_sensors() -> None:
    rng = np.random.default_rng(3)
    base = np.tile(np.linspace(0.1, 0.9, 200, dtype=np.float32), (150, 1))
    sigma = 0.01 + 0.02 * base                 # a level-dependent noise
    stack = np.stack([base + rng.normal(0, 1, base.shape) * sigma for _ in range(5)])
    got = np.sqrt(noise_variance(stack.astype(np.float32), base))
    # the 10th percentile of local variances over 25 pixels: within 25 % of the truth
    ratio = got[:, 10:-10] / sigma[:, 10:-10]
    assert 0.75 < np.median(ratio) < 1.1


def test_too_few_lit_pixels_to_measure_the_noise_mark_nothing_static() -> None:
    stack = np.zeros((8, 200, 200), np.float32)
    rng = np.random.default_rng(4)
    stack[:, 50:70, 50:100] = rng.random((8, 20, 50))   # 1000 lit pixels, changing
    level = np.median(stack, axis=0)
    assert not np.any(np.isfinite(noise_variance(stack, level)))
    assert not static_pixels(stack, level).any()
    assert occluder_mask(list(stack)).shape == (200, 200)   # no crash; the dark rules only


def test_a_steady_arm_below_full_scale_is_static_however_bright() -> None:
    """The brightest steady thing is not taken for saturation: full scale is 1."""
    rng = np.random.default_rng(5)
    frames = []
    for k in range(9):
        f = 0.1 + 0.4 * cv2.GaussianBlur(rng.random((150, 200)), (0, 0), 2) * (1 + 0.05 * k)
        f = np.round((f + rng.normal(0, 0.003, f.shape)) * 255) / 255
        f[:, 80:100] = 180 / 255                # a lit arm, noise-free, 8-bit
        frames.append(f.astype(np.float32))
    stack = np.stack(frames)
    assert static_pixels(stack, np.median(stack, axis=0))[:, 84:96].mean() > 0.99


def test_a_12_bit_sensors_clipped_wall_is_not_an_occluder() -> None:
    """12-bit data in 16-bit files (read as a fraction of 65535): wall clipped at 4095 in
    every frame does not vary, and is still not taken for an occluder, while a steady
    arm below full scale is; the full scale is the data's bit depth, not the file's."""
    rng = np.random.default_rng(6)
    frames = []
    for k in range(9):
        wall = 0.3 + 0.4 * cv2.GaussianBlur(rng.random((150, 200)), (0, 0), 2) * (1 + 0.05 * k)
        counts = np.round(wall * 4095 + rng.normal(0, 3.0, wall.shape))
        counts[:, 80:100] = 3000                # a lit arm, 12-bit, noise-free
        counts[:30] = 4095                      # the near wall: clipped in every frame
        frames.append((np.clip(counts, 0, 4095).astype(np.uint16) / 65535).astype(np.float32))
    stack = np.stack(frames)
    static = static_pixels(stack, np.median(stack, axis=0))
    assert static[40:, 84:96].mean() > 0.99
    assert not static[:30].any()
    assert static[40:, :70].mean() < 0.01
    assert full_scale(float(stack.max())) == pytest.approx(4095 / 65535)
    assert full_scale(16 / 255) == 16383 / 65535 and full_scale(1.0) == 1.0


def test_a_large_frame_is_masked_at_about_mask_rows_with_the_same_result(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame taller than MASK_ROWS is area-averaged by a whole factor first; the mask
    comes back at the frame's pixels (odd sizes too) and agrees with the one computed at
    full resolution but near the occluders' edges, which the margin covers anyway."""
    from pipestitch.mosaic import occluders

    rng = np.random.default_rng(3)
    shape = (401, 481)                         # rows not a multiple of the factor
    frames = []
    for k in range(7):
        wall = cv2.resize(rng.random((100, 120)), shape[::-1], interpolation=cv2.INTER_CUBIC)
        f = (0.35 + 0.25 * wall) * (0.9 + 0.1 * np.sin(k))
        f[:, 200:232] = 0.6                    # a lit arm, fixed in the image
        f[300:, 300:360] = 0.02                # a dark mount
        frames.append(np.clip(f + rng.normal(0, 0.004, shape), 0, 1).astype(np.float32))
    monkeypatch.setattr(occluders, "MASK_ROWS", 200)    # the frames' factor: 2
    reduced = occluder_mask(frames)
    monkeypatch.setattr(occluders, "MASK_ROWS", 10_000)
    full = occluder_mask(frames)
    assert reduced.shape == full.shape == shape
    assert reduced[:, 204:228].all() and reduced[304:, 304:356].all()
    edges = cv2.dilate((full ^ cv2.erode(full.astype(np.uint8), np.ones((3, 3)))
                        .astype(bool)).astype(np.uint8), np.ones((9, 9))).astype(bool)
    assert np.mean(reduced[~edges] != full[~edges]) < 0.002
