"""Photometric evidence on the mirror ambiguity: the true pair of LED frames agrees best."""

from __future__ import annotations

import cv2
import numpy as np

from pipestitch.geometry import PipeSection, Pose, laser_ring
from pipestitch.mosaic.photometric import (
    StripPair,
    _compare,
    contrast_strips,
    pair_costs,
    strip_misfit,
)
from pipestitch.pose.fit import ConicModel, Hypothesis, PoseFit, pose_from_conic
from pipestitch.pose.ring import prepare_laser_frame
from pipestitch.simulate.render import Renderer

R = 32.5


def _fit_of(poses: list[Pose]) -> PoseFit:
    return PoseFit(True, "", tuple(Hypothesis(p, R, 0.0, 0.0, 0.0) for p in poses), 100, 1.0)


def _strips_at(renderer: Renderer, z: float):
    """A frame at ``z`` with 3° of tilt; its "fit" holds the truth and its mirror (-alpha,
    -beta, offset moved so the ring stays the same, from the ring's conic)."""
    pose = Pose.from_degrees(2.4, -1.8, 3.0, -2.0, 0.0, z)
    ring = laser_ring(pose, PipeSection(R), 16.0, n_points=90)
    sols = pose_from_conic(*ConicModel.from_estimate(ring[:, :2]).normalised(), 16.0)
    true_first = sorted(sols, key=lambda s: abs(s[0].alpha - pose.alpha))
    _, led = renderer.render_pair(pose, np.random.default_rng(int(z)))
    fit = _fit_of([p for p, _ in true_first])
    return contrast_strips(prepare_laser_frame(led), renderer.camera, fit)


def test_photometric_costs_prefer_the_true_pair(holed_renderer: Renderer) -> None:
    # Two frames 5 mm apart
    costs = pair_costs(_strips_at(holed_renderer, 20.0), _strips_at(holed_renderer, 25.0))
    assert costs[0, 0] == 0.0
    assert costs[1, 1] > 5 and costs[0, 1] > 5 and costs[1, 0] > 5


def test_frames_that_share_under_half_the_window_give_no_evidence(
        holed_renderer: Renderer) -> None:
    # The same two hypotheses, frames 5 mm apart and 30 mm apart (the window runs from
    # 0.6 to 1.8 radii ahead: 39 mm): the far pair shares too little wall to say anything
    # (its best peak <= 0.02; without the floor its costs reach 20).
    near = pair_costs(_strips_at(holed_renderer, 20.0), _strips_at(holed_renderer, 25.0))
    assert near.max() > 5
    far = pair_costs(_strips_at(holed_renderer, 20.0), _strips_at(holed_renderer, 50.0))
    np.testing.assert_array_equal(far, np.zeros((2, 2)))


def test_costs_read_the_strips_as_prepared_once(holed_renderer: Renderer) -> None:
    # The pair's costs come from each strip prepared once (its validity, count and
    # spectrum): the misfits are 1 - cv2.phaseCorrelate's peak of the strips themselves,
    # with 0 where they have no data, to the bit.
    first, second = _strips_at(holed_renderer, 20.0), _strips_at(holed_renderer, 25.0)
    for pair in (first, second):
        for strip, prepared in zip(pair.strips, pair.comparable, strict=True):
            assert prepared.valid.dtype == bool
            np.testing.assert_array_equal(prepared.valid, np.isfinite(strip))
            assert prepared.count == np.count_nonzero(np.isfinite(strip)) > 100
    for a, pa in zip(first.strips, first.comparable, strict=True):
        for b, pb in zip(second.strips, second.comparable, strict=True):
            assert _compare(pa, pb)[1] == np.count_nonzero(np.isfinite(a) & np.isfinite(b))
    misfit = np.array([[strip_misfit(a, b) for b in second.strips] for a in first.strips])
    window = cv2.createHanningWindow(first.strips[0].shape[::-1], cv2.CV_32F)
    window = np.tile(window[window.shape[0] // 2], (window.shape[0], 1))   # along z only
    expected = np.array([[1.0 - cv2.phaseCorrelate(np.nan_to_num(b, nan=0.0),
                                                   np.nan_to_num(a, nan=0.0), window)[1]
                          for b in second.strips] for a in first.strips])
    np.testing.assert_array_equal(misfit, expected)
    costs = pair_costs(first, second)
    # 0 at the best-agreeing combination, N_eff/2 log(U / U_min) elsewhere (capped)
    assert costs[np.unravel_index(np.argmin(misfit), misfit.shape)] == 0.0
    rebuilt = pair_costs(StripPair(first.strips), StripPair(second.strips))
    np.testing.assert_array_equal(costs, rebuilt)
    assert np.all((costs > 0) == (misfit > misfit.min()))
