"""Texture sampling past OpenCV's remap limit: the same samples as OpenCV gives on
textures it accepts."""

from __future__ import annotations

import cv2
import numpy as np

from pipestitch.simulate._remap import REMAP_MAX, remap_points, remap_wrap


def _one_at_a_time(texture: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Reference: each point sampled by ``cv2.remap`` from the few columns around it (a
    whole-pixel shift of the map: the same interpolation weights, the same value)."""
    out = np.empty(x.size, texture.dtype)
    for i, (xi, yi) in enumerate(zip(x, y, strict=True)):
        c0 = int(np.floor(xi)) - 2
        out[i] = cv2.remap(np.ascontiguousarray(texture[:, c0:c0 + 6]),
                           np.array([[xi - c0]], np.float32), np.array([[yi]], np.float32),
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)[0, 0]
    return out


def test_texture_wider_than_opencv_remaps_is_sampled_exactly() -> None:
    """A long run's wall texture passes OpenCV's 32767-column limit of cv2.remap."""
    rows, cols = 64, 80_000
    assert cols > 2 * REMAP_MAX
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float32)
    texture = (0.001 * c + 0.1 * np.sin(r / 5)).astype(np.float32)
    rng = np.random.default_rng(0)
    # One frame may reach more than 32767 columns (far down the pipe): 3 crops here.
    x = rng.uniform(1_000, 79_000, 3000).astype(np.float32)
    y = rng.uniform(5, 55, 3000).astype(np.float32)
    want = _one_at_a_time(texture, x, y)
    np.testing.assert_array_equal(remap_points(texture, x, y), want)
    got = remap_wrap(texture, x.reshape(30, 100), y.reshape(30, 100))
    np.testing.assert_array_equal(got.ravel(), want)
    # ... and those are the texture's values: bilinear on the sine's curvature and
    # OpenCV's 1/32-pixel weights leave 5e-4 at most here, where one column off
    # would be 1e-3 and a wrong crop far more
    assert np.abs(want - (0.001 * x + 0.1 * np.sin(y / 5))).max() < 7e-4
