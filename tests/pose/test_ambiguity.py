"""Choosing between mirror hypotheses: envelope decides, continuity carries, never guess."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pipestitch.geometry import BodyEnvelope, PipeSection, Pose, laser_ring
from pipestitch.pose.ambiguity import coincide, envelope_costs, resolve_run
from pipestitch.pose.fit import ConicModel, Hypothesis, PoseFit, pose_from_conic

D = 16.0
R = 32.5


def exact_fit(pose: Pose, radius_mm: float = R, plane_mm: float = D,
              std: dict[str, float] | None = None) -> PoseFit:
    """Both hypotheses of a noise-free ring (closed form), true one first or second,
    each with the 1-sigma ``std`` a fit would report (none by default)."""
    ring = laser_ring(pose, PipeSection(radius_mm), plane_mm, n_points=90)
    sols = pose_from_conic(*ConicModel.from_estimate(ring[:, :2]).normalised(), plane_mm)
    hyps = tuple(Hypothesis(p, r, 0.0, 0.0, 0.0, dict(std or {})) for p, r in sols)
    return PoseFit(True, "", hyps, 90, 1.0)


def is_true(fit: PoseFit, index: int, pose: Pose) -> bool:
    h = fit.hypotheses[index].pose
    return abs(h.alpha - pose.alpha) < 1e-6 and abs(h.beta - pose.beta) < 1e-6


def assert_undecided(fits: list[PoseFit]) -> None:
    """Without any evidence, every frame is flagged undecided."""
    choices = resolve_run(fits, np.zeros((len(fits), 2)))
    assert all(c.ambiguous and c.reason == "undecided" for c in choices)


def evidence_at(fits: list[PoseFit], poses: list[Pose], k: int) -> np.ndarray:
    """Unary costs with evidence against the mirror of frame ``k`` only (as if the
    envelope had ruled it out there)."""
    unary = np.zeros((len(fits), 2))
    unary[k, 1 - (0 if is_true(fits[k], 0, poses[k]) else 1)] = 40.0
    return unary


def track(n: int = 30, tilt_deg: float = 3.0) -> list[Pose]:
    t = np.linspace(0, 1, n)
    return [Pose.from_degrees(tilt_deg * np.cos(2 * s), tilt_deg * np.sin(2 * s), 2.0 * s, -1.0)
            for s in t]


def test_envelope_penalises_a_body_through_the_wall() -> None:
    body = BodyEnvelope(145.0, 45.0)
    # 4° of tilt with the camera 4.5 mm off axis: the mirror pose has the rear of the
    # body outside a 65 mm pipe, the true one fits.
    pose = Pose.from_degrees(4.0, 0.0, 0.0, -4.5)
    fit = exact_fit(pose)
    costs = envelope_costs(fit, body)
    true_index = 0 if is_true(fit, 0, pose) else 1
    assert costs[true_index] == 0.0
    assert costs[1 - true_index] > 50


def test_continuity_carries_a_decision_but_never_makes_one() -> None:
    poses = track()
    fits = [exact_fit(p) for p in poses]
    # No evidence at all: every frame is ambiguous (the mirror track is as smooth).
    assert_undecided(fits)
    # Evidence in one frame (say the envelope ruled the mirror out there): the whole
    # track follows, and every choice is the true pose.
    k = 12
    choices = resolve_run(fits, evidence_at(fits, poses, k))
    assert choices[k].reason == "envelope"
    for fit, pose, c in zip(fits, poses, choices, strict=True):
        assert not c.ambiguous and is_true(fit, c.chosen, pose)
    assert {c.reason for i, c in enumerate(choices) if i != k} == {"continuity"}


def test_failed_frames_and_coinciding_hypotheses() -> None:
    poses = [Pose.from_degrees(0.0, 0.0, 1.0, 1.0), Pose.from_degrees(3.0, 1.0, 0.0, 0.0)]
    fits = [exact_fit(poses[0]), PoseFit(False, "ring not found"), exact_fit(poses[1])]
    choices = resolve_run(fits, np.zeros((3, 2)))
    assert choices[0].reason == "coincide" and not choices[0].ambiguous
    assert choices[1].chosen is None and choices[1].reason == "no fit"
    assert choices[2].ambiguous
    with pytest.raises(ValueError, match="expected shape"):
        resolve_run(fits, np.zeros((2, 2)))


def test_both_hypotheses_impossible_is_flagged() -> None:
    poses = track(5)
    fits = [exact_fit(p) for p in poses]
    unary = np.zeros((5, 2))
    unary[2] = [80.0, 90.0]  # e.g. an oval pipe read as 15° of tilt
    choices = resolve_run(fits, unary)
    assert choices[2].ambiguous and choices[2].reason == "infeasible"


def test_hypotheses_coincide_within_the_frames_own_uncertainty() -> None:
    """0.05° of tilt 170 mm from the plane: the hypotheses are 0.1° and 0.3 mm apart,
    inside the 1-sigma a 300 mm pipe's frame has there (0.15° and 0.45 mm, measured on
    frames rendered through a 1232 x 1028 lens); the same frame known to a 65 mm
    pipe's precision at 3° of tilt (0.06°, 0.016 mm) is ambiguous."""
    pose = Pose.from_degrees(0.05, 0.0, 10.0, -5.0)
    coarse = {"alpha": np.deg2rad(0.15), "beta": np.deg2rad(0.15), "dx_mm": 0.45, "dy_mm": 0.45}
    fine = {"alpha": np.deg2rad(0.06), "beta": np.deg2rad(0.06), "dx_mm": 0.016, "dy_mm": 0.016}
    assert coincide(exact_fit(pose, 150.0, 170.0, coarse))
    assert not coincide(exact_fit(pose, 150.0, 170.0, fine))
    choice = resolve_run([exact_fit(pose, 150.0, 170.0, coarse)], np.zeros((1, 2)))[0]
    assert choice.reason == "coincide" and not choice.ambiguous


def _wandering_track(seed: int, radius_mm: float, n: int = 40) -> list[Pose]:
    """A probe wandering in a large pipe: a random walk of 2.5 mm per frame in each
    offset (within 40 mm of the axis), tilts of 1-3°."""
    rng = np.random.default_rng(seed)
    offset = np.clip(np.cumsum(rng.normal(0.0, 2.5, (n, 2)), axis=0), -0.27 * radius_mm,
                     0.27 * radius_mm)
    return [Pose.from_degrees(2.5 + 0.5 * np.sin(k / 5), -1.5 + 0.5 * np.cos(k / 7), *offset[k])
            for k in range(n)]


@pytest.mark.parametrize("seed", range(6))
def test_continuity_never_decides_in_a_large_pipe(seed: int) -> None:
    """A 300 mm pipe with the laser plane 170 mm ahead: the mirror poses' offsets are
    ~15 mm apart (2 d tan(tilt)) and the probe wanders by millimetres per frame. The
    transition scale follows the pipe (a fixed 1 mm made the rougher of the two tracks
    look impossible, so continuity alone chose, wrongly for all 40 frames of seed 4);
    without evidence every frame stays undecided, and one frame of evidence carries."""
    radius, plane = 150.0, 170.0
    poses = _wandering_track(seed, radius)
    fits = [exact_fit(p, radius, plane) for p in poses]
    assert_undecided(fits)
    choices = resolve_run(fits, evidence_at(fits, poses, 20))
    decided = [is_true(f, c.chosen, p) for f, p, c in zip(fits, poses, choices, strict=True)
               if not c.ambiguous]
    assert all(decided) and len(decided) == len(fits)


def test_independent_poses_are_not_linked_by_continuity() -> None:
    """Poses drawn independently, as the reference protocol's are (here tilts up to 20°
    and offsets up to 8 mm on each axis): one frame says nothing about the next, so
    without evidence every frame stays undecided; the rougher of two random tracks is
    not the wrong one."""
    rng = np.random.default_rng(7)
    poses = [Pose.from_degrees(*rng.uniform(-20, 20, 2), *rng.uniform(-8, 8, 2))
             for _ in range(30)]
    assert_undecided([exact_fit(p) for p in poses])


def test_a_frame_without_a_finite_radius_does_not_silence_the_flags() -> None:
    """A NaN in one frame's fit must not turn every margin into NaN (which would compare
    as decided): the frames stay undecided without evidence."""
    fits = [exact_fit(p) for p in track()]
    bad = fits[5].hypotheses
    fits[5] = replace(fits[5], hypotheses=(replace(bad[0], radius_mm=float("nan")), bad[1]))
    assert_undecided(fits)


def _pair_favouring(a: int, b: int) -> np.ndarray:
    """Photometric costs of a pair whose comparison found combination (a, b) best."""
    costs = np.full((2, 2), 30.0)
    costs[a, b] = 0.0
    return costs


def test_photometric_comparisons_that_contradict_each_other_decide_nothing() -> None:
    """Along a stretch of compared frames the best chain follows every comparison and
    pays nothing; when one comparison must be overruled (it found both frames' mirrors
    best, its neighbours the true poses), which one is wrong is not known: the stretch's
    comparisons are dropped, and its frames are flagged unless other evidence decides
    them. A stretch whose comparisons agree decides its frames."""
    poses = track(12)
    fits = [exact_fit(p) for p in poses]
    true = [0 if is_true(f, 0, p) else 1 for f, p in zip(fits, poses, strict=True)]
    agree = {k: _pair_favouring(true[k], true[k + 1]) for k in range(6, 11)}
    choices = resolve_run(fits, np.zeros((12, 2)), pairwise=agree)
    assert all(not c.ambiguous and c.chosen == t for c, t in zip(choices[6:], true[6:],
                                                                 strict=True))
    assert {c.reason for c in choices[6:]} == {"photometric"}

    contradicting = {**agree, 8: _pair_favouring(1 - true[8], 1 - true[9])}
    choices = resolve_run(fits, np.zeros((12, 2)), pairwise=contradicting)
    assert all(c.ambiguous and c.reason == "undecided" for c in choices)

    # the same stretch after frames that the comparisons of an earlier stretch decided
    # (frames 4 -> 6 not compared): continuity carries that decision over it
    first = {k: _pair_favouring(true[k], true[k + 1]) for k in range(4)}
    choices = resolve_run(fits, np.zeros((12, 2)), pairwise={**first, **contradicting})
    assert all(not c.ambiguous and c.chosen == t for c, t in zip(choices, true, strict=True))
    assert {c.reason for c in choices[6:]} == {"continuity"}
