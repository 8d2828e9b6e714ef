"""The two frames of a pair are taken at two instants: the LED frame's pose is not the
laser frame's.

SPEC: the probe moves a little between the two frames of a pair. The ring measures the
laser frame's pose; the mosaic is made of the LED frames, and the LED frames refine
the poses (:mod:`pipestitch.mosaic.refine`) with the ring as their prior. With the
prior on the laser frame's pose, a pose 0.03-0.15 mm and 0.03-0.08 deg away at the LED
frame's instant was reconciled by trading offset for tilt: the refined tilts were
0.11-0.28 deg off on runs whose LED frames were taken 1-2.5 mm further on, and their
stated sigma 4-11 times too small.

The probe moves smoothly, so the LED frame's pose lies between its pair's ring pose
and the next pair's (the previous pair's when the LED frame comes first), a share of
the way that a camera's fixed frame timing keeps constant along a run (a half for a
video alternating laser and LED frames at a steady rate). That share is measured: the
ring search finds how far out along the rays the LED frame's wall lies
(:mod:`pipestitch.pose.pair_motion`), that is how far the probe moved on between the
two frames, and registration finds the step between pairs (:func:`led_share`); where
the wall under the laser line cannot tell, the LED frames' overlaps do
(:func:`patch_led_share`). The refinement's prior is then the ring poses interpolated
at that share, and the refined poses (the LED frames') are taken back to the laser
frames' instants for the poses the output states (as the ring measures them:
:func:`laser_instant_poses`; z and roll: :func:`laser_instant`).

Pure: views, links and poses in, priors and poses out.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from typing import TypeVar

import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import Pose
from pipestitch.mosaic.refine import PRIOR_SIGMA, PatchShifts, prior_share
from pipestitch.mosaic.register import Link
from pipestitch.pose.ring import ring_centre

__all__ = ["laser_instant", "laser_instant_poses", "led_instant_priors", "led_share",
           "patch_led_share", "pose_vector", "ring_px_per_mm", "same_reference"]

T = TypeVar("T", float, np.ndarray)

MIN_FRAMES = 3        # pairs that must measure the share before it is taken
# ... and at least this share of the pairs registration stepped from: where most pairs
# cannot tell (a test chart moving sideways: 3 of 11, measuring 0.05 where 0.2 was
# made), the few that do are not to be trusted over the LED frames' overlaps (0.18)
MIN_MEASURED = 0.5
MIN_STEP_PX = 2.0     # a step to the next pair moving the ring's wall less (px) says nothing
SIGNIFICANT = 3.0     # sigmas from 0 a share the patches find must be to be taken


def ring_px_per_mm(camera: CameraModel, plane_distance_mm: float, radius_mm: float) -> float:
    """How far out (px) the image of the wall under the laser ring moves when a centred
    probe moves 1 mm on along the pipe."""
    wall = np.array([[radius_mm, 0.0, plane_distance_mm], [radius_mm, 0.0, plane_distance_mm - 1]])
    px = camera.project(wall) - ring_centre(camera)
    return float(np.linalg.norm(px[1]) - np.linalg.norm(px[0]))


def led_share(shift_px: Mapping[int, float], links: Sequence[Link],
              px_per_mm: float) -> float | None:
    """The share of the step to the next pair by which the LED frames were taken after
    their laser frames (negative: before) as the wall under the laser line tells it: the
    median over the pairs whose LED frame's shift the ring search measured (``shift_px``,
    :attr:`RingDetection.led_shift_px`: 0 where it saw the frames taken together, NaN
    where it could not tell) and whose step registration measured; None where fewer
    than ``MIN_FRAMES`` pairs, or fewer than ``MIN_MEASURED`` of the pairs with a step,
    tell (a few chance detections, or a few frames of a wall that mostly cannot tell, do
    not make a run's share)."""
    if not math.isfinite(px_per_mm) or px_per_mm <= 0:
        return None
    step = {ln.i: ln.dz_mm for ln in links if ln.j == ln.i + 1 and math.isfinite(ln.dz_mm)
            and abs(ln.dz_mm) * px_per_mm >= MIN_STEP_PX}
    shares = [shift_px[i] / px_per_mm / step[i] for i in step
              if math.isfinite(shift_px.get(i, math.nan))]
    if not step or len(shares) < max(MIN_FRAMES, MIN_MEASURED * len(step)):
        return None
    return float(np.clip(np.median(shares), -1.0, 1.0))


def patch_led_share(poses: Mapping[int, Pose], information: Mapping[int, np.ndarray | None],
                    observations: Sequence[PatchShifts],
                    jacobians: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]]
                    ) -> tuple[float, float]:
    """The share of a step by which the LED frames follow their laser frames as their
    patches tell it, where the wall under the laser line cannot (brushed metal, a test
    chart moving sideways): the share at which the rings' priors, each moved by it along
    the rings' track, agree best with the LED frames' overlaps
    (:func:`pipestitch.mosaic.refine.prior_share`); (share, its sigma), the share
    within [-1, 1].

    Each LED frame's strips warp by its pose's error at its instant: strips unwrapped
    with the rings' poses disagree where the LED frames were taken elsewhere, by an
    amount that grows with how far; the patch shifts between overlapping strips measure
    that (on simulated aluminium and test-chart runs whose LED frames followed 0.2 and
    0.5 of a step later, 0.20-0.53 found, 0.66 at worst; no share taken together:
    docs/benchmarks.md). The track's direction at a frame
    is the slope of the rings' poses of its neighbours (:func:`_track_slope`), not the
    step to the next ring (as :func:`led_instant_priors` moves the priors): that step
    holds the frame's own ring error, which the patches also see: on a run taken together
    whose poses change by about their rings' errors from pair to pair, it made a share of
    0.2-0.45 (tests/pipeline/test_pair_timing.py). Where the rings' poses barely change,
    the share moves the priors little, and its sigma says so.
    """
    direction = {i: -slope for i in poses if (slope := _track_slope(poses, i)) is not None}
    share, sigma = prior_share(observations, jacobians, information, direction)
    return float(np.clip(share, -1.0, 1.0)), sigma


SLOPE_FRAMES = 4   # neighbours on each side whose rings give a frame's track slope


def _track_slope(poses: Mapping[int, Pose], i: int) -> np.ndarray | None:
    """The rings' poses' change per frame at frame ``i``: the derivative there of the
    least-squares quadratic (a line with fewer than four) through its neighbours within
    ``SLOPE_FRAMES`` (itself left out); None with fewer than two."""
    near = [k for k in range(i - SLOPE_FRAMES, i + SLOPE_FRAMES + 1) if k != i and k in poses]
    if len(near) < 2:
        return None
    offset = np.array(near, float) - i
    design = np.vander(offset, 3 if len(near) >= 4 else 2, increasing=True)
    values = np.array([pose_vector(poses[k]) for k in near])
    return np.linalg.lstsq(design, values, rcond=None)[0][1]


def pose_vector(pose: Pose) -> np.ndarray:
    """(alpha, beta, dx, dy) of ``pose`` (rad, mm): the refinement's unknowns."""
    return np.array([pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm])


def led_instant_priors(poses: Mapping[int, Pose], information: Mapping[int, np.ndarray | None],
                       share: float) -> tuple[dict[int, np.ndarray | None],
                                              dict[int, np.ndarray]]:
    """Each frame's ring prior moved to its LED frame's instant: (information, the pose
    error it is centred on) as :func:`pipestitch.mosaic.refine.solve_in_windows` takes
    them.

    The ring poses of the frame and of its neighbour (the next pair when ``share`` > 0,
    else the previous one) interpolated at ``|share|`` (at the run's end, extrapolated
    from the neighbour on the other side), their covariances combined as those of two
    rings measured apart; the error is the ring pose less that (the strips were
    unwrapped with the ring pose). A frame without a neighbour, or whose own or
    neighbour's information is missing, keeps its own prior. The information returned
    is positive semidefinite (extrapolated, a ring's free direction would otherwise come
    out below the weak prior's).
    """
    info: dict[int, np.ndarray | None] = dict(information)
    errors: dict[int, np.ndarray] = {}
    # the refinement's weak prior, which it adds to every frame's: a section-free ring
    # prior leaves the direction an oval would take singular, and this bounds it
    weak = np.diag(1.0 / PRIOR_SIGMA**2)
    for i in poses:
        weights = _instant_weights(i, poses, share)
        if weights is None or not (_finite(information.get(i))
                                   and _finite(information.get(weights[2]))):
            continue
        own, other, n = weights
        cov = (own ** 2 * np.linalg.inv(information[i] + weak)
               + other ** 2 * np.linalg.inv(information[n] + weak))
        moved = np.linalg.inv(cov) - weak
        values, vectors = np.linalg.eigh(0.5 * (moved + moved.T))
        info[i] = (vectors * np.clip(values, 0.0, None)) @ vectors.T
        errors[i] = pose_vector(poses[i]) - (own * pose_vector(poses[i])
                                             + other * pose_vector(poses[n]))
    return info, errors


def _instant_weights(i: int, frames: Mapping[int, object], share: float
                     ) -> tuple[float, float, int] | None:
    """(a, b, n): the value at frame i's LED instant is a v_i + b v_n, n its neighbour
    ahead by the sign of ``share`` (interpolated), or behind where there is none
    (extrapolated at the same pace); None without either, or with no share."""
    s, ahead = abs(share), (1 if share > 0 else -1)
    if s == 0:
        return None
    if i + ahead in frames:
        return 1.0 - s, s, i + ahead
    if i - ahead in frames:
        return 1.0 + s, -s, i - ahead
    return None


def _finite(matrix: np.ndarray | None) -> bool:
    return matrix is not None and bool(np.all(np.isfinite(matrix)))


def laser_instant(values: Mapping[int, T], share: float, *, average: bool = True
                  ) -> dict[int, T]:
    """Values at the laser frames' instants (poses as (alpha, beta, dx, dy) arrays, z,
    roll) from those at the LED frames'; a frame with no neighbour is kept as it is.

    ``average``: each laser frame's instant lies between its own LED frame's and the
    previous pair's (the next pair's where the LED frames come first), ``|share|`` of
    the way from its own: the two are interpolated there (where that neighbour is
    missing, at the run's start or, the LED frames first, at its end, extrapolated from
    the other side). Each value's error is then averaged with its
    neighbour's (weights 1 - s and s: 0.7 times a frame's error at a share of 0.5) and a
    smooth track's bend leaves s (1 - s) / 2 of it. Otherwise each is moved back by
    ``|share|`` of the way to the pair ahead (the inverse, to first order, of the
    interpolation :func:`led_instant_priors` makes: weights 1 + s and -s, 1.6 times a
    frame's error, s (1 + s) / 2 of a bend), exact where the probe moves at a steady
    speed between pairs and changes it at the laser frames. The refined poses, whose
    noise is the larger part of their error, are averaged (a smaller median tilt error
    on seven of eight simulated runs along smooth tracks, up to 2.8 times:
    docs/benchmarks.md), and the track's bend taken off as far as it shows
    (:func:`laser_instant_poses`); z and roll, which registration measures to microns
    and hundredths of a degree, are moved back."""
    out = dict(values)
    for i, v in values.items():
        weights = _instant_weights(i, values, -share if average else share)
        if weights is None:
            continue
        own, other, n = weights
        # moved back: the neighbour's value stands for its ring's (first order)
        out[i] = own * v + other * values[n] if average else v - other * (values[n] - v)
    return out


def laser_instant_poses(poses: Mapping[int, np.ndarray], sigmas: Mapping[int, np.ndarray],
                        share: float, track: Collection[int] | None = None
                        ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """Refined poses ((alpha, beta, dx, dy): :func:`pose_vector`) and their one-sigma
    uncertainties (NaN where not known) at the laser frames' instants, from those at the
    LED frames' (``track``: the frames whose poses are the LED frames', default all).

    Each pose is interpolated between its own LED frame's and its neighbour's
    (:func:`laser_instant`), which leaves ``h = s (1 - s) / 2`` of the track's second
    difference there (``s = |share|``: the bend of a smooth track). Where both its
    neighbours have poses, a share ``k`` of that second difference is taken off, per
    parameter: the share of least expected square error, ``(B + C / h) / (B + N)``
    clipped to [0, 1] (between the interpolation and the parabola through the three LED
    poses), where ``B`` is the variance of the track's second differences beyond what
    the stated uncertainties explain (:func:`_track_bend`, over ``track``), ``N`` the
    frame's second difference's noise variance and ``C`` its covariance with the
    interpolation's noise (the poses' errors taken as independent): all of it where the
    track bends far more than the poses scatter (the offsets of a probe wandering across
    the pipe), none where the scatter hides the bend. The stated sigma: the poses'
    sigmas through the weights as if their errors were one (neighbours refined together
    share much of theirs: the bound whatever their correlation), the bend left (``(1 -
    k) h`` of it, ``s (1 + s) / 2`` where extrapolated at the run's end), and what the
    parabola misses (``s (1 - s^2) / 6`` of the track's third difference, its variance
    beyond the scatter measured as the bend's).
    """
    s = abs(share)
    out, std = dict(poses), dict(sigmas)
    if s == 0:
        return out, std
    on_track = poses if track is None else {i: poses[i] for i in track if i in poses}
    bend = _track_bend(on_track, sigmas)
    turn = _track_bend(on_track, sigmas, order=3)   # what a parabola misses
    half = s * (1 - s) / 2
    for i in poses:
        found = _instant_weights(i, poses, -share)
        if found is None:
            continue
        own, other, n = found
        weights = {i: np.full(4, own), n: np.full(4, other)}
        left = (half if other > 0 else s * (1 + s) / 2) * np.sqrt(bend)
        if i - 1 in poses and i + 1 in poses:
            keep = _bend_share(weights, sigmas, bend, half, i)
            for d, c in SECOND_DIFFERENCE:
                weights[i + d] = weights.get(i + d, 0.0) - keep * half * c
            left = np.hypot((1 - keep) * left, keep * s * (1 - s * s) / 6 * np.sqrt(turn))
        out[i] = sum(w * poses[j] for j, w in weights.items())
        # a frame of weight 0 (the unused neighbour of a parameter kept as interpolated)
        # adds nothing, not even an unknown sigma
        scatter = sum(np.where(w != 0, np.abs(w) * sigmas[j], 0.0)
                      for j, w in weights.items())
        std[i] = np.hypot(scatter, left)
    return out, std


SECOND_DIFFERENCE = ((-1, 1.0), (0, -2.0), (1, 1.0))   # (frame offset, tap) about a frame


def _bend_share(weights: Mapping[int, np.ndarray], sigmas: Mapping[int, np.ndarray],
                bend: np.ndarray, half: float, i: int) -> np.ndarray:
    """Per parameter, the share of frame ``i``'s second difference taken off its
    interpolation (``weights``) that minimises the expected square error, in [0, 1]:
    ``(B + C / h) / (B + N)`` (:func:`laser_instant_poses`); 0 where not known."""
    variance = {d: sigmas[i + d] ** 2 for d, _ in SECOND_DIFFERENCE}
    noise = sum(c * c * variance[d] for d, c in SECOND_DIFFERENCE)
    shared = sum(weights.get(i + d, 0.0) * c * variance[d] for d, c in SECOND_DIFFERENCE)
    with np.errstate(invalid="ignore", divide="ignore"):
        keep = (bend + shared / half) / (bend + noise)
    return np.where(np.isfinite(keep), np.clip(keep, 0.0, 1.0), 0.0)


def _track_bend(poses: Mapping[int, np.ndarray], sigmas: Mapping[int, np.ndarray],
                order: int = 2) -> np.ndarray:
    """Per parameter: the variance of the track's difference of ``order`` (2: its bend,
    3: how the bend changes) beyond what the poses' sigmas explain (their noise taken as
    independent; 0 where they explain it all, or where no ``order + 1`` consecutive
    frames have poses with sigmas)."""
    taps = np.array([math.comb(order, k) * (-1) ** k for k in range(order + 1)], float)
    rows = [(sum(c * poses[i + k] for k, c in enumerate(taps)),
             sum(c * c * sigmas[i + k] ** 2 for k, c in enumerate(taps)))
            for i in poses if all(i + k in poses for k in range(order + 1))]
    if not rows:
        return np.zeros(4)
    difference, noise = (np.array(r) for r in zip(*rows, strict=True))
    finite = np.isfinite(noise) & np.isfinite(difference)
    count = np.count_nonzero(finite, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        square = np.where(finite, difference ** 2, 0.0).sum(axis=0) / count
        expected = np.where(finite, noise, 0.0).sum(axis=0) / count
    return np.where(count > 0, np.maximum(square - expected, 0.0), 0.0)


def same_reference(moved: Mapping[int, float], before: Mapping[int, float],
                   reference: Mapping[int, float] | None = None,
                   scale: float = 1.0) -> dict[int, float]:
    """``moved`` (z or roll moved to the laser frames' instants) offset back to the
    reference ``before`` had: the median offset 0 against ``reference`` (the odometer's
    readings times its fitted ``scale``, the IMU's roll) where it has readings of the
    frames, else the first frame where it was."""
    common = [i for i in moved if reference is not None and i in reference
              and math.isfinite(reference[i]) and math.isfinite(moved[i])]
    if common:
        offset = float(np.median([reference[i] * scale - moved[i] for i in common]))
    elif moved and (first := min(moved)) in before:
        offset = before[first] - moved[first]
    else:
        return dict(moved)
    return {i: v + offset for i, v in moved.items()}
