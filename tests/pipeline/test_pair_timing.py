"""The LED frames' instant within their pairs: the share measured from the ring's shifts
and registration's steps, the rings' priors moved to it and the refined poses moved back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import Pose
from pipestitch.mosaic.refine import PRIOR_SIGMA
from pipestitch.mosaic.register import Link
from pipestitch.pipeline.pair_timing import (
    _track_bend,
    laser_instant,
    laser_instant_poses,
    led_instant_priors,
    led_share,
    pose_vector,
    ring_px_per_mm,
    same_reference,
)


def _links(steps_mm: list[float]) -> list[Link]:
    return [Link(i, i + 1, dz, 0.0, 1.0, 0.01, 0.01) for i, dz in enumerate(steps_mm)]


def test_the_rings_wall_moves_out_as_the_probe_moves_on() -> None:
    # a probe 1 mm further on sees the wall under its ring 1 mm further back: further out
    scale = ring_px_per_mm(default_camera("half"), 16.0, 32.5)
    assert 5.0 < scale < 10.0


def test_the_share_is_the_shifts_over_the_steps() -> None:
    px_per_mm = 7.5
    steps = [5.0, 5.5, 4.5, 5.0, 6.0]
    shifts = {i: 0.3 * step * px_per_mm for i, step in enumerate(steps)}
    assert led_share(shifts, _links(steps), px_per_mm) == pytest.approx(0.3)
    # pulled back: steps and shifts both negative, the LED frames still after
    backwards = {i: -v for i, v in shifts.items()}
    assert led_share(backwards, _links([-s for s in steps]), px_per_mm) == pytest.approx(0.3)
    # the LED frame first: it sees the wall the laser frame will, further in
    assert led_share(backwards, _links(steps), px_per_mm) == pytest.approx(-0.3)


def test_no_share_without_enough_measured_pairs() -> None:
    px_per_mm, steps = 7.5, [5.0, 5.0, 5.0, 5.0]
    # two pairs tell, the others cannot (NaN) or have no shift at all
    assert led_share({0: 10.0, 1: 11.0}, _links(steps), px_per_mm) is None
    assert led_share({0: 10.0, 1: 11.0, 2: math.nan, 3: math.nan}, _links(steps),
                     px_per_mm) is None
    # at a standstill a step says nothing of the share
    assert led_share({i: 5.0 for i in range(4)}, _links([0.05] * 4), px_per_mm) is None


def test_pairs_told_still_make_a_share_of_zero() -> None:
    # the wall says the frames were taken together (0), not that it cannot tell (NaN)
    px_per_mm, steps = 7.5, [5.0] * 10
    still = {i: 0.0 for i in range(10)}
    assert led_share(still, _links(steps), px_per_mm) == 0.0
    # a few chance shifts among them do not move the median
    chance = still | {2: 0.6 * 5.0 * px_per_mm, 7: 0.4 * 5.0 * px_per_mm}
    assert led_share(chance, _links(steps), px_per_mm) == 0.0


def _track(n: int) -> dict[int, Pose]:
    """Poses moving steadily: each parameter a straight line in the frame number."""
    return {i: Pose(alpha=np.deg2rad(1.0 + 0.2 * i), beta=np.deg2rad(-0.5 + 0.1 * i),
                    dx_mm=0.5 - 0.05 * i, dy_mm=0.02 * i) for i in range(n)}


@pytest.mark.parametrize("share", [0.3, -0.4])
def test_priors_at_the_led_instant_and_poses_back_at_the_laser_instant(share: float) -> None:
    rings = _track(6)
    sigma = np.array([np.deg2rad(0.1), np.deg2rad(0.1), 0.02, 0.02])
    info = {i: np.diag(1.0 / sigma**2) for i in rings}
    moved, centre = led_instant_priors(rings, info, share)
    assert sorted(centre) == sorted(rings)   # the end frames extrapolated
    step = pose_vector(rings[1]) - pose_vector(rings[0])
    for i, ring in rings.items():
        # the prior's centre: where the pose is at the LED frame's instant
        np.testing.assert_allclose(pose_vector(ring) - centre[i],
                                   pose_vector(ring) + share * step, atol=1e-12)
        # two rings combined: their prior is tighter than one's in the middle of the run,
        # looser where extrapolated (and never the weak prior's alone)
        inside = 0 <= i + (1 if share > 0 else -1) < len(rings)
        ratio = np.diag(moved[i]) / np.diag(info[i])
        assert np.all(ratio > 1.0) if inside else np.all(ratio < 1.0)
        assert np.all(np.diag(moved[i]) > 1.0 / PRIOR_SIGMA**2)
    led = {i: pose_vector(r) + share * step for i, r in rings.items()}
    back = laser_instant(led, share)
    for i, ring in rings.items():
        np.testing.assert_allclose(back[i], pose_vector(ring), atol=1e-12)
    assert laser_instant({i: float(i) for i in range(4)}, 0.0) == {i: float(i) for i in range(4)}


@pytest.mark.parametrize("share", [0.2, 0.5, -0.3])
def test_back_at_the_laser_instant_interpolates_between_led_frames(share: float) -> None:
    # a bending track p(t) = t^2 / 2 (a pair a unit of time): the LED frame k is at
    # t = k + share; the laser frame i lies between two LED frames, and linear
    # interpolation there is off by s (1 - s) / 2 of the bend (extrapolating from the pair
    # ahead would be s (1 + s) / 2 off)
    s = abs(share)
    led = {k: 0.5 * (k + share) ** 2 for k in range(6)}
    back = laser_instant(led, share)
    inside = range(1, 6) if share > 0 else range(0, 5)
    for i in inside:
        assert abs(back[i] - 0.5 * i**2) == pytest.approx(s * (1 - s) / 2, abs=1e-12)
    moved = laser_instant(led, share, average=False)
    for i in range(0, 5) if share > 0 else range(1, 6):
        assert abs(moved[i] - 0.5 * i**2) == pytest.approx(s * (1 + s) / 2, abs=1e-12)
    # and noise is averaged, not amplified: weights 1 - s and s (1 + s and -s moved back)
    rng = np.random.default_rng(3)
    noise = {k: rng.normal(size=4000) for k in range(6)}
    spread = np.std(laser_instant(noise, share)[3])
    assert spread == pytest.approx(np.sqrt((1 - s) ** 2 + s**2), rel=0.05)
    spread = np.std(laser_instant(noise, share, average=False)[3])
    assert spread == pytest.approx(np.sqrt((1 + s) ** 2 + s**2), rel=0.05)


def _bending_run(share: float, bend: float, sigma: float, seed: int, n: int = 40
                 ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray], np.ndarray]:
    """LED-instant poses of a track bending along the run (each parameter a sine of
    period 32 pairs, amplitude ``bend``) with independent noise ``sigma``, their stated
    sigmas, and the track at the laser instants (the truth). What a parabola through
    three poses misses of it is ~(1 + s) / 3 x 2 pi / 32 of the interpolation's error."""
    rng = np.random.default_rng(seed)

    def track(t: np.ndarray) -> np.ndarray:
        return bend * np.sin(2 * np.pi * t / 32.0)[:, None] * np.array([1.0, 0.5, 2.0, -1.0])

    frames = np.arange(n, dtype=float)
    led = track(frames + share) + rng.normal(0.0, sigma, (n, 4))
    return ({i: led[i] for i in range(n)}, {i: np.full(4, sigma) for i in range(n)},
            track(frames))


@pytest.mark.parametrize("share", [0.5, 0.2, -0.3])
def test_poses_back_at_the_laser_instant_take_off_the_bend_the_track_shows(share: float
                                                                           ) -> None:
    # a track that bends far more than its poses scatter: the parabola through three LED
    # poses, where the interpolation is s (1 - s) / 2 of the bend off
    led, sigmas, truth = _bending_run(share, bend=1.0, sigma=1e-4, seed=1)
    back, std = laser_instant_poses(led, sigmas, share)
    linear = laser_instant(led, share)
    inside = range(1, 39)
    error = np.array([back[i] - truth[i] for i in inside])
    off = np.array([linear[i] - truth[i] for i in inside])
    assert np.sqrt(np.mean(error**2)) < 0.15 * np.sqrt(np.mean(off**2))
    # the stated sigma holds the error left (what the parabola misses, and the noise)
    ratio = np.abs(error) / np.array([std[i] for i in inside])
    assert np.median(ratio) < 1.0 and np.max(ratio) < 3.0
    # ... and not the interpolation's error, which was taken off
    stated = np.median(np.array([std[i] for i in inside]), axis=0)
    assert np.all(stated < 0.25 * np.sqrt(np.mean(off**2, axis=0)))


@pytest.mark.parametrize("share", [0.5, -0.3])
def test_poses_back_at_the_laser_instant_interpolate_where_the_noise_hides_a_bend(
        share: float) -> None:
    # a straight track: nothing to take off beyond the scatter, the interpolation as it
    # is; over many runs the stated sigma is not below the scatter of the errors
    errors, stated, same = [], [], 0
    for seed in range(200):
        rng = np.random.default_rng(seed)
        led = {i: np.full(4, 0.3 * (i + share)) + rng.normal(0.0, 0.01, 4) for i in range(12)}
        sigmas = {i: np.full(4, 0.01) for i in range(12)}
        back, std = laser_instant_poses(led, sigmas, share)
        linear = laser_instant(led, share)
        # the interpolation's noise and the second difference's are anticorrelated
        # below a share of 2/3: a bend the noise hides is not taken off, unless the
        # chance bend of ten second differences is far above their noise
        differs = np.max(np.abs(np.array([back[i] - linear[i] for i in range(12)])))
        assert differs < 0.01
        same += differs == 0
        errors.append([back[i] - 0.3 * i for i in range(1, 11)])
        stated.append([std[i] for i in range(1, 11)])
    assert same > 100   # the interpolation itself on most runs
    scatter = np.std(np.array(errors), axis=(0, 1))
    assert np.all(np.median(np.array(stated), axis=(0, 1)) >= scatter)
    assert np.all(np.median(np.array(stated), axis=(0, 1)) < 1.6 * scatter)


def test_the_bend_share_taken_off_is_the_one_of_least_square_error() -> None:
    # a track of constant bend d (second difference) a little above the poses' noise:
    # over many runs of 60 frames the share the code takes off (its B measured on each
    # run) gives a smaller mean square error than the interpolation, the parabola, or
    # the best share for the true B, (B + C / h) / (B + N), +- 0.25, and comes within 2 %
    # of that best share's
    share, d, sigma, n = 0.5, 4.0, 1.0, 60
    half = share * (1 - share) / 2
    best = (d * d + (3 * share - 2) * sigma**2 / half) / (d * d + 6 * sigma**2)
    errors: dict[str, list[np.ndarray]] = {name: [] for name in (
        "code", "linear", "parabola", "less", "more", "best")}
    for seed in range(200):
        rng = np.random.default_rng(seed)
        led = {i: np.full(4, 0.5 * d * (i + share) ** 2) + rng.normal(0.0, sigma, 4)
               for i in range(n)}
        back, _ = laser_instant_poses(led, {i: np.full(4, sigma) for i in led}, share)
        linear = laser_instant(led, share)
        for i in range(1, n - 1):
            truth = 0.5 * d * i**2
            second = led[i - 1] - 2 * led[i] + led[i + 1]
            errors["code"].append(back[i] - truth)
            errors["linear"].append(linear[i] - truth)
            for name, k in (("parabola", 1.0), ("less", best - 0.25), ("more", best + 0.25),
                            ("best", best)):
                errors[name].append(linear[i] - k * half * second - truth)
    square = {name: float(np.mean(np.square(v))) for name, v in errors.items()}
    assert square["code"] < min(square[name] for name in ("linear", "parabola", "less",
                                                           "more"))
    assert square["code"] < 1.02 * square["best"]


def test_the_tracks_bend_beyond_its_scatter() -> None:
    # pure noise: nothing beyond the scatter (second differences' noise 6 sigma^2,
    # third 20 sigma^2); a parabola: its second difference's square; a cubic: its third's
    rng = np.random.default_rng(5)
    n, sigma = 4000, np.full(4, 0.1)
    noise = {i: rng.normal(0.0, 0.1, 4) for i in range(n)}
    sigmas = {i: sigma for i in range(n)}
    for order, taps in ((2, 6), (3, 20)):   # within 5 % of the noise's variance
        assert np.all(_track_bend(noise, sigmas, order) < 0.05 * taps * 0.01)
    bent = {i: noise[i] + 0.3 * i**2 / 2 for i in range(n)}
    assert _track_bend(bent, sigmas) == pytest.approx(np.full(4, 0.3**2), rel=0.05)
    cubic = {i: noise[i] + 0.5 * i**3 / 6 for i in range(n)}
    assert _track_bend(cubic, sigmas, 3) == pytest.approx(np.full(4, 0.5**2), rel=0.05)
    assert np.all(_track_bend({0: sigma, 1: sigma}, sigmas) == 0)   # too few frames


def test_poses_at_the_runs_ends_state_the_bend_their_extrapolation_leaves() -> None:
    # the first frame (LED frames after their laser frames: extrapolated from the next
    # pair) and the last: no parabola, the bend's whole share in their sigma
    share, n = 0.5, 40

    def track(t: np.ndarray) -> np.ndarray:   # the bend largest at the run's ends
        return np.cos(2 * np.pi * t / 80.0)[:, None] * np.ones(4)

    led_poses = track(np.arange(n) + share)
    led = {i: led_poses[i] for i in range(n)}
    back, std = laser_instant_poses(led, {i: np.full(4, 1e-6) for i in led}, share)
    truth = track(np.arange(n, dtype=float))
    for i in (0, n - 1):
        ratio = np.abs(back[i] - truth[i]) / std[i]
        assert np.all(ratio > 0.3) and np.all(ratio < 2.0)


def test_poses_back_at_the_laser_instant_without_a_share_are_as_refined() -> None:
    led, sigmas, _ = _bending_run(0.0, bend=1.0, sigma=1e-3, seed=2, n=5)
    back, std = laser_instant_poses(led, sigmas, 0.0)
    assert all(np.array_equal(back[i], led[i]) and np.array_equal(std[i], sigmas[i])
               for i in led)


def test_a_frame_alone_or_without_its_neighbours_information_keeps_its_prior() -> None:
    rings = {0: Pose(), 5: Pose(alpha=0.01)}
    info = {0: np.eye(4), 5: np.eye(4)}
    moved, centre = led_instant_priors(rings, info, 0.5)
    assert centre == {} and moved[0] is info[0]
    rings = _track(2)
    moved, centre = led_instant_priors(rings, {0: np.eye(4), 1: None}, 0.5)
    assert 0 not in centre and moved[0] is not None
    assert led_instant_priors(rings, {0: np.eye(4), 1: np.eye(4)}, 0.0)[1] == {}


def test_a_few_chance_shifts_in_a_long_run_make_no_share() -> None:
    px_per_mm, steps = 7.5, [5.0] * 1000
    chance = {i: 0.6 * 5.0 * px_per_mm for i in (10, 400, 800)}
    assert led_share(chance, _links(steps), px_per_mm) is None
    every_tenth = {i: 0.3 * 5.0 * px_per_mm for i in range(0, 1000, 10)}
    assert led_share(every_tenth, _links(steps), px_per_mm) is None   # most cannot tell
    most = {i: 0.3 * 5.0 * px_per_mm for i in range(1000) if i % 3}
    assert led_share(most, _links(steps), px_per_mm) == pytest.approx(0.3)


def test_an_extrapolated_prior_on_a_ring_with_a_free_direction_is_semidefinite() -> None:
    # the section-free ring prior leaves a direction free (an oval could take it)
    free = np.array([1.0, 0.0, 0.0, 0.3]) / np.hypot(1.0, 0.3)
    info = np.diag([4e5, 4e5, 2.5e3, 2.5e3])
    info = info - np.outer(info @ free, info @ free) / (free @ info @ free)
    rings = _track(3)
    moved, centre = led_instant_priors(rings, {i: info for i in rings}, 0.5)
    assert 2 in centre   # the last frame: extrapolated
    for matrix in moved.values():
        assert np.min(np.linalg.eigvalsh(matrix)) >= -1e-9 * np.max(np.abs(matrix))


def test_positions_back_at_the_laser_instant_keep_their_reference() -> None:
    before = {0: 0.0, 1: 5.0, 2: 10.0, 3: 15.0}         # LED instants, first frame at 0
    moved = laser_instant(before, 0.5, average=False)    # 2.5 mm back each
    assert same_reference(moved, before) == pytest.approx({0: 0.0, 1: 5.0, 2: 10.0, 3: 15.0})
    odometer = {0: 100.0, 1: 105.2, 2: 109.8, 3: 115.0}  # read at the laser frames' instants
    on_it = same_reference(moved, before, odometer, scale=1.0)
    assert np.median([odometer[i] - on_it[i] for i in on_it]) == pytest.approx(0.0)
