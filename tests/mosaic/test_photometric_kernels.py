"""The comparison strips' local contrast, compiled, against the numpy expressions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.imaging import gaussian_blur, nanmedian
from pipestitch.mosaic.photometric import _contrast


def _numpy_contrast(strip: np.ndarray) -> np.ndarray:
    """The local contrast as numpy expressions (what the compiled passes replace)."""
    valid = np.isfinite(strip)
    filled = np.where(valid, strip, 0).astype(np.float32)
    weight = gaussian_blur(valid.astype(np.float32), 6.0)
    local = gaussian_blur(filled, 6.0) / np.maximum(weight, 1e-6)
    med = nanmedian(strip) if valid.any() else 0.0
    contrast = filled / np.maximum(local, 1e-6) - 1
    dark = ~valid | (filled < 0.3 * local) | (local < 0.25 * med)
    dark = cv2.dilate(dark.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return np.where(dark | (weight < 0.5), np.nan, contrast).astype(np.float32)


@pytest.mark.parametrize("case", ["textured", "holes and arm", "dim", "no data"])
def test_contrast_is_the_numpy_expressions_to_the_bit(case: str) -> None:
    rng = np.random.default_rng(3)
    strip = cv2.GaussianBlur(rng.random((96, 70)).astype(np.float32), (0, 0), 1.5) + 0.2
    if case == "holes and arm":
        strip[10:20, 5:15] = np.nan                 # unseen nodes
        strip[40:44, :] *= 0.05                     # a dark arm across the strip
        strip[60:63, 30:33] = 0.0                   # a hole
        strip[0, 0] = np.inf
    elif case == "dim":
        strip *= 1e-6                               # below the 1e-6 floors
    elif case == "no data":
        strip[:] = np.nan
    got = _contrast(strip)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, _numpy_contrast(strip))
    if case == "textured":
        assert np.isfinite(got).mean() > 0.5   # the comparison is not empty
