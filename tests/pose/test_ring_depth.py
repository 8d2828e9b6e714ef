"""The ring detector's noise floor follows the frame's bit depth: a dim ring of a
12-bit sensor stored in 16-bit files is found against its own noise, not against a
floor set by 8-bit quantisation."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.pose.ring import detect_ring


def _ring_counts(amplitude: float, noise: float, radius_px: float = 300.0) -> np.ndarray:
    """A half-size frame in 12-bit counts: background 200, a ring of Gaussian
    cross-section 1.6 px and ``amplitude`` counts, Gaussian noise of ``noise`` counts."""
    cam = default_camera("half")
    rows, cols = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    axis = cam.project(np.array([[0.0, 0.0, 1.0]]))[0]
    r = np.hypot(cols - axis[0], rows - axis[1])
    counts = 200.0 + amplitude * np.exp(-0.5 * ((r - radius_px) / 1.6) ** 2)
    counts += np.random.default_rng(0).normal(0.0, noise, counts.shape)
    return np.clip(np.round(counts), 0, 4095)


@pytest.mark.parametrize("amplitude", [40.0, 400.0])
def test_a_dim_12_bit_ring_in_a_16_bit_file_is_found(amplitude: float) -> None:
    counts = _ring_counts(amplitude, noise=2.0)
    det = detect_ring(counts.astype(np.uint16), default_camera("half"))
    # 40 counts is 20 sigmas of the 2-count noise, but 0.16 of an 8-bit step of the
    # file's range: the 8-bit floor (a quarter of a step, 64 counts) hid it.
    assert det.coverage >= 0.95
    cam = default_camera("half")
    axis = cam.project(np.array([[0.0, 0.0, 1.0]]))[0]
    radius = np.hypot(*(det.best() - axis).T)
    assert np.median(np.abs(radius - 300.0)) < 0.2
    # The same frame as 8 bits (counts / 4095 * 255): 2.5 steps high at 40 counts, and
    # lost against the 8-bit floor there; found at 400 counts (25 steps).
    eight = np.round(counts / 4095 * 255).astype(np.uint8)
    assert (detect_ring(eight, cam).coverage >= 0.95) == (amplitude > 100)
