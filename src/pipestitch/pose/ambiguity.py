"""Choosing between the two mirror hypotheses of every frame of a run.

One laser ring fits two poses exactly (see :mod:`pipestitch.pose.fit`), so a single
frame's ring never decides. Evidence that does:

* the **probe envelope**: the rigid body (probe.toml length and diameter) must fit
  inside the pipe; a hypothesis that puts it through the wall is penalised by how
  far, relative to the uncertainty of that check;
* **photometric consistency** of consecutive LED frames (pair costs, ``pairwise``).
  A stretch of compared frames whose comparisons contradict each other (the best
  chain must overrule one of them) gives no evidence: a texture that fools the
  comparison, or ring poses far enough off to warp a strip more than its mirror does,
  would otherwise decide silently and wrongly (:func:`_contradicted`).

**Temporal continuity** then carries a decision along the run: a min-sum (Viterbi)
pass over a two-state chain whose transition cost is the pose change between
consecutive hypotheses, up to a jump (``JUMP_SCALES``): poses that change by more
than a probe moves between frames are linked by nothing. Continuity alone never
decides: the mirror track is exactly as smooth as the true one, so a run without any
deciding evidence stays ambiguous.
Each frame's margin is the difference between the best total cost with its state
forced to either hypothesis; below ``min_margin`` the frame is flagged ambiguous.
Frames whose two hypotheses coincide (tilt near zero) are not ambiguous: both give
the same pose within the uncertainty.

"Coincide" is within the frame's own 1-sigma pose uncertainty (the fit's ``std``, from
its pixel noise), not a fixed 0.05° / 0.05 mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise as pairwise_indices

import numpy as np
from scipy.special import stdtrit

from pipestitch.geometry import BodyEnvelope, PipeSection
from pipestitch.pose.fit import Hypothesis, PoseFit

__all__ = ["BODY_TOLERANCE_RADII", "STEP_ANGLE_DEG", "STEP_OFFSET_RADII", "Choice",
           "clearance_sigma_mm", "coincide", "consistently_positive", "envelope_costs",
           "hypothesis_distance", "resolve_run"]


@dataclass(frozen=True, slots=True)
class Choice:
    """Decision for one frame.

    Attributes
    ----------
    chosen : int or None
        Index of the chosen hypothesis (None for frames without a fit).
    ambiguous : bool
        True when the evidence does not decide (the chosen one is only the likelier).
    reason : str
        What decided: "envelope", "photometric", "continuity", "coincide", "undecided",
        "infeasible" (neither hypothesis fits a circular pipe) or "no fit".
    margin : float
        Cost difference between the two choices (negative log-likelihood units).
    """

    chosen: int | None
    ambiguous: bool
    reason: str
    margin: float


def hypothesis_distance(h1: Hypothesis, h2: Hypothesis, *, angle_scale_rad: float,
                        offset_scale_mm: float) -> float:
    """Normalised pose difference: sqrt((dangle/scale)² + (doffset/scale)²)."""
    p, q = h1.pose, h2.pose
    dang = np.hypot(p.alpha - q.alpha, p.beta - q.beta) / angle_scale_rad
    doff = np.hypot(p.dx_mm - q.dx_mm, p.dy_mm - q.dy_mm) / offset_scale_mm
    return float(np.hypot(dang, doff))


# How far the declared body may differ from the real one where it meets the wall
# (machining, wheels or skids, the wall's roughness), as a fraction of the pipe's
# radius (0.5 mm in a 65 mm pipe, 2.3 mm in a 300 mm one): the floor of the uncertainty
# of a body's clearance when the ring pins its pose exactly.
BODY_TOLERANCE_RADII = 0.015
# The pose change between consecutive frames that continuity expects: a degree of tilt,
# and an offset change of this fraction of the pipe's radius (~1 mm in a 65 mm pipe):
# a probe's lateral play, and so its wander, grows with the pipe.
STEP_ANGLE_DEG = 1.0
STEP_OFFSET_RADII = 0.03


def clearance_sigma_mm(h: Hypothesis, body: BodyEnvelope) -> float:
    """1-sigma uncertainty of the body's clearance for hypothesis ``h``.

    The ring fit's own uncertainty (``h.std``, from the frame's pixel noise) moves the
    body's rear rim by the tilt's sigma times the body's length plus the offset's sigma
    (on simulated runs the tilt errors match the stated sigma: 0.03-0.33° against
    0.08-0.34°), combined with ``BODY_TOLERANCE_RADII`` of the ring's radius. So a frame
    seen through a coarse lens, a far laser plane or a noisy line is judged with the
    leeway its own pose has.
    """
    tilt, offset = pose_sigma(h)
    return float(np.hypot(BODY_TOLERANCE_RADII * h.radius_mm, body.length_mm * tilt + offset))


# Exact (noise-free) fits report no uncertainty: their poses are the same below this
# (radians, and this fraction of the pipe's radius for offsets), i.e. within rounding.
EXACT = 1e-6


def pose_sigma(h: Hypothesis) -> tuple[float, float]:
    """1-sigma of the tilt (radians) and of the offset (mm) of ``h``, from the fit's own
    ``std`` (0 where it gives none)."""
    s = {k: float(v) if np.isfinite(v) else 0.0 for k, v in h.std.items()}
    return (float(np.hypot(s.get("alpha", 0.0), s.get("beta", 0.0))),
            float(np.hypot(s.get("dx_mm", 0.0), s.get("dy_mm", 0.0))))


def _fit_sigma(fit: PoseFit) -> np.ndarray:
    """The larger 1-sigma (tilt rad, offset mm) of a frame's hypotheses, at least rounding."""
    sigmas = np.max([pose_sigma(h) for h in fit.hypotheses], axis=0)
    radius = max(h.radius_mm for h in fit.hypotheses)
    return np.maximum(sigmas, [EXACT, EXACT * radius])


def coincide(fit: PoseFit) -> bool:
    """Whether a frame's two hypotheses are the same pose within its own uncertainty.

    They coincide when their difference is below 1 sigma of the fit (tilt and offset
    together: sqrt((dtilt / sigma_tilt)² + (doffset / sigma_offset)²) < 1, each sigma
    the larger of the two hypotheses'): choosing either then errs by less than the pose
    is known to. At the frame's own sigma, not a fixed 0.05° / 0.05 mm: the same
    separation is well inside the uncertainty of a 300 mm pipe's frame (0.15°, 0.45 mm
    at 0.05° of tilt, plane 170 mm ahead) and outside that of a 65 mm pipe's at 3° of
    tilt (0.06°, 0.016 mm).
    """
    h0, h1 = fit.hypotheses
    sigma = _fit_sigma(fit)
    return hypothesis_distance(h0, h1, angle_scale_rad=sigma[0], offset_scale_mm=sigma[1]) < 1.0


def envelope_costs(fit: PoseFit, body: BodyEnvelope | None) -> np.ndarray:
    """Cost of each hypothesis from the probe body's fit inside the pipe (0 without a
    declared body).

    A hypothesis whose body crosses the wall by v mm costs (v / sigma)² / 2, sigma from
    :func:`clearance_sigma_mm`. The wall is the ring's own radius.
    """
    costs = np.zeros(2)
    if body is None:
        return costs
    for i, h in enumerate(fit.hypotheses):
        clearance = body.clearance_mm(h.pose, PipeSection(h.radius_mm))
        costs[i] = 0.5 * (min(clearance, 0.0) / clearance_sigma_mm(h, body)) ** 2
    return costs


def _photo_evidence(photo: dict[int, np.ndarray], idx: list[int], k: int) -> float:
    """How strongly the photometric costs next to frame idx[k] prefer one of its states."""
    ev = 0.0
    if idx[k] in photo:  # frame k is the first of the pair
        p = photo[idx[k]]
        ev = max(ev, abs(p[0].min() - p[1].min()))
    if k > 0 and idx[k - 1] in photo:  # frame k is the second of the pair
        p = photo[idx[k - 1]]
        ev = max(ev, abs(p[:, 0].min() - p[:, 1].min()))
    return ev


def _min_marginals(u: np.ndarray, steps: list[np.ndarray], photo: dict[int, np.ndarray],
                   idx: list[int]) -> np.ndarray:
    """(K, 2): the least total cost of the chain with frame idx[k] in each state
    (min-sum forward and backward passes; transitions ``steps`` plus the photometric
    costs of the pairs that have them)."""
    trans = [t + photo.get(idx[k], np.zeros((2, 2))) for k, t in enumerate(steps)]
    fwd = np.zeros((len(idx), 2))
    fwd[0] = u[0]
    for k, t in enumerate(trans, start=1):
        fwd[k] = u[k] + np.min(fwd[k - 1][:, None] + t, axis=0)
    bwd = np.zeros((len(idx), 2))
    for k in range(len(idx) - 2, -1, -1):
        bwd[k] = np.min(trans[k] + (u[k + 1] + bwd[k + 1])[None, :], axis=1)
    return fwd + bwd


def _contradicted(total: np.ndarray, photo: dict[int, np.ndarray], idx: list[int],
                  min_margin: float) -> list[int]:
    """The photometric pairs (keys of ``photo``) of every stretch of consecutive compared
    frames in which the best chain pays ``min_margin`` or more for one pair's comparison.

    Each pair's costs are a likelihood ratio that is 0 for the combination it finds
    best; on a stretch of frames whose comparisons agree, the best chain follows them
    all and pays nothing. Paying for one means two comparisons of the stretch disagree
    (a wall whose texture fools the comparison, a ring pose far enough off to warp the
    strip more than its mirror does): which one is wrong is not known, so the stretch's
    comparisons are all dropped and its frames decided by the rest (the body, continuity)
    or flagged.
    """
    best = np.argmin(total, axis=1)
    stretches: list[list[int]] = []
    for k, a in enumerate(idx[:-1]):
        if a not in photo:
            continue
        if k > 0 and stretches and stretches[-1][-1] == idx[k - 1]:   # follows it
            stretches[-1].append(a)
        else:
            stretches.append([a])
    position = {a: k for k, a in enumerate(idx)}
    out = []
    for stretch in stretches:
        paid = [photo[a][best[position[a]], best[position[a] + 1]] for a in stretch]
        if max(paid) >= min_margin:
            out.extend(stretch)
    return out


def _reason(u: np.ndarray, photo_evidence: float, min_margin: float) -> str:
    if abs(u[0] - u[1]) >= min_margin:
        return "envelope"
    return "photometric" if photo_evidence >= min_margin else "continuity"


# A pose change of more than this many transition scales between two frames is a jump
# (a jolt, frames far apart, poses drawn independently): every jump is as likely as any
# other, so two hypotheses that both jump there cost the same and continuity carries
# nothing across (a Gaussian motion model mixed with a small chance of any pose).
JUMP_SCALES = 5.0


def _transition(fa: PoseFit, fb: PoseFit, gap: int, angle_rad: float,
                offset_mm: float) -> np.ndarray:
    cost = np.zeros((2, 2))
    scale = np.sqrt(gap)
    for i, ha in enumerate(fa.hypotheses):
        for j, hb in enumerate(fb.hypotheses):
            d = min(hypothesis_distance(ha, hb, angle_scale_rad=angle_rad * scale,
                                        offset_scale_mm=offset_mm * scale), JUMP_SCALES)
            cost[i, j] = 0.5 * d * d
    return cost


def resolve_run(fits: list[PoseFit], unary: np.ndarray, *,
                pairwise: dict[int, np.ndarray] | None = None,
                step_angle_deg: float = STEP_ANGLE_DEG, step_offset_mm: float | None = None,
                min_margin: float = 5.0, infeasible_cost: float = 50.0) -> list[Choice]:
    """Choose a hypothesis per frame from per-frame costs and temporal continuity.

    Parameters
    ----------
    fits : list of PoseFit
        One per frame in run order; frames with ``ok`` False are skipped (the chain
        connects their neighbours with a proportionally looser transition).
    unary : numpy.ndarray, shape (N, 2)
        Per-frame cost of each hypothesis (envelope ...).
    pairwise : dict of int -> numpy.ndarray (2, 2), optional
        Photometric costs between frame k and the next frame with a fit, keyed by k
        (:func:`pipestitch.mosaic.photometric.pair_costs`).
    step_angle_deg : float
        Typical tilt change between consecutive frames (transition scale).
    step_offset_mm : float, optional
        The same for the offset; default ``STEP_OFFSET_RADII`` of the median fitted
        radius (1 mm when no radius is finite).
    min_margin : float
        Margin below which a frame is flagged ambiguous (5 ≈ 150:1 odds).
    infeasible_cost : float
        When both hypotheses cost at least this much, neither is physically possible:
        the frame is flagged "infeasible" (ambiguous) and gives the chain no evidence.

    Returns
    -------
    list of Choice
    """
    n = len(fits)
    if unary.shape != (n, 2):
        raise ValueError(f"unary: expected shape ({n}, 2), got {unary.shape}")
    idx = [i for i, f in enumerate(fits) if f.ok and len(f.hypotheses) == 2]
    choices = [Choice(None, False, "no fit", 0.0) for _ in range(n)]
    if not idx:
        return choices
    if step_offset_mm is None:
        radii = [h.radius_mm for i in idx for h in fits[i].hypotheses
                 if np.isfinite(h.radius_mm) and h.radius_mm > 0]
        step_offset_mm = STEP_OFFSET_RADII * float(np.median(radii)) if radii else 1.0
    ang, off = np.deg2rad(step_angle_deg), step_offset_mm
    u = unary[idx].copy()
    # Both hypotheses impossible (an oval pipe read as tilt, a wrong calibration):
    # such a frame carries no evidence for the chain and is flagged.
    impossible = np.min(u, axis=1) >= infeasible_cost
    u[impossible] = 0.0
    steps = [_transition(fits[a], fits[b], b - a, ang, off) for a, b in pairwise_indices(idx)]
    photo = dict(pairwise or {})
    total = _min_marginals(u, steps, photo, idx)
    for _ in range(len(idx)):   # each round clears at least one stretch
        contradicted = _contradicted(total, photo, idx, min_margin)
        if not contradicted:
            break
        for a in contradicted:
            del photo[a]
        total = _min_marginals(u, steps, photo, idx)
    for k, i in enumerate(idx):
        margin = float(abs(total[k, 0] - total[k, 1]))
        chosen = int(np.argmin(total[k]))
        if impossible[k]:
            choices[i] = Choice(chosen, True, "infeasible", margin)
        elif coincide(fits[i]):
            choices[i] = Choice(chosen, False, "coincide", margin)
        elif not margin >= min_margin:   # a NaN margin decides nothing either
            choices[i] = Choice(chosen, True, "undecided", margin)
        else:
            choices[i] = Choice(chosen, False, _reason(u[k], _photo_evidence(photo, idx, k),
                                                       min_margin), margin)
    return choices


def consistently_positive(gains: np.ndarray | list[float], significance: float = 0.01,
                          min_count: int = 3) -> bool:
    """Whether paired evidence favours one hypothesis over the other replicate after
    replicate: ``gains`` (one per replicate, positive where the first hypothesis did
    better) have a mean above zero at ``significance`` (one-sided Student t-test; at
    least ``min_count`` replicates, else False)."""
    gains = np.asarray(gains, dtype=float)
    if gains.size < max(2, min_count):
        return False
    spread = float(np.std(gains, ddof=1))
    t = float(np.mean(gains)) / max(spread / np.sqrt(gains.size), 1e-12)
    return bool(t > float(stdtrit(gains.size - 1, 1 - significance)))
