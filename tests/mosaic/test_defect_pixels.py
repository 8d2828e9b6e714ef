"""A sensor's hot and dead pixels found from LED frames of a moving wall and repaired
(mosaic/occluders.py defect_pixels, camera/frames.py repair_pixels)."""

from __future__ import annotations

import numpy as np

from pipestitch.camera import repair_pixels
from pipestitch.mosaic.occluders import defect_pixels


def _frames(n: int = 11, seed: int = 0) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """A textured wall moving past the camera (a new texture each frame), with 0.1 % of
    the pixels stuck at full scale and a few stuck at 0."""
    rng = np.random.default_rng(seed)
    shape = (240, 320)
    hot = rng.choice(shape[0] * shape[1], 80, replace=False)
    dead = rng.choice(shape[0] * shape[1], 10, replace=False)
    frames = []
    for _ in range(n):
        wall = rng.normal(110, 25, shape)
        wall = np.clip(wall + rng.normal(0, 3, shape), 0, 255)
        wall.flat[hot] = 255
        wall.flat[dead] = 0
        frames.append(wall.astype(np.uint8))
    truth = np.zeros(shape, bool)
    truth.flat[hot] = truth.flat[dead] = True
    return frames, truth, hot


def test_stuck_pixels_are_found_and_nothing_else() -> None:
    frames, truth, _ = _frames()
    rows, cols = defect_pixels(frames)
    found = np.zeros_like(truth)
    found[rows, cols] = True
    assert found[truth].all()
    assert not found[~truth].any()               # no pixel of the moving wall


def test_a_wall_feature_that_stays_a_few_frames_is_no_defect() -> None:
    frames, _, _ = _frames()
    for f in frames[:5]:            # a bright spot seen in 5 of 11 frames
        f[50, 60] = 255
    rows, cols = defect_pixels(frames)
    assert not np.any((rows == 50) & (cols == 60))


def test_too_few_frames_find_nothing() -> None:
    frames, _, _ = _frames(n=4)
    assert len(defect_pixels(frames)[0]) == 0


def test_repaired_pixels_take_their_neighbours_median() -> None:
    grey = np.full((5, 6), 0.5, np.float32)
    grey[2, 3] = 1.0
    grey[0, 0] = 0.0          # a corner: its neighbours clamped at the border
    repair_pixels(grey, np.array([2, 0]), np.array([3, 0]))
    assert grey[2, 3] == 0.5 and grey[0, 0] == 0.5
    assert np.all(grey == 0.5)


def test_a_black_border_and_a_sensor_s_fine_pattern_are_no_defects() -> None:
    """8-bit frames of a smooth wall inside a lens' image circle (black outside) with a
    per-pixel offset pattern of under one grey level: the spread is measured where the
    wall is seen, and a defect stands out by a few grey levels at least."""
    rng = np.random.default_rng(1)
    rows, cols = np.mgrid[:240, :320]
    circle = (rows - 120) ** 2 + (cols - 160) ** 2 < 100 ** 2
    pattern = rng.normal(0, 0.8, circle.shape)
    hot = (50, 140)
    frames = []
    for k in range(11):
        wall = 100 + 20 * np.sin((cols + 7 * k) / 15.0) + pattern + rng.normal(0, 1, circle.shape)
        wall[~circle] = 0
        wall[hot] = 255
        frames.append(np.clip(np.round(wall), 0, 255).astype(np.uint8))
    found_rows, found_cols = defect_pixels(frames)
    assert list(zip(found_rows.tolist(), found_cols.tolist(), strict=True)) == [hot]
