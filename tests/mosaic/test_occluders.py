"""The occluder mask: what stays fixed in the image is masked, what moves with the wall is not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.mosaic.occluders import occluder_mask


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
