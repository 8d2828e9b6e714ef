"""Tilted probe or oval pipe: which one a run shows when its rings cannot say.

One ring cannot tell a tilted probe in a round pipe from a less tilted one in an oval
pipe (:mod:`pipestitch.pose.section`): 5 % ovality read as a circle is ~18° of tilt,
0.6 % ~6°. A declared probe body says "oval" for a frame whose circle pose it cannot
hold (:mod:`pipestitch.pipeline.posing`); a run without a body, or with one small
enough to hold the circle poses, has nothing in its rings that does. The LED frames
do: unwrapped with the true tilt and section, consecutive frames show the same wall up
to one shift, with a wrong tilt the strip is warped and no shift explains it
(:mod:`pipestitch.mosaic.photometric`).

So, once the pose pass has fitted every frame as a circle, up to five pairs of
consecutive frames (no frame in two pairs; the odometer's step leaves their comparison
strips half their length in common) whose circle tilt is well above the ring's own tilt
error (a tilt within that error says nothing about its cause) are taken from the middle
of the run, and each frame is unwrapped twice: with no tilt and the oval section the ring
then gives (:func:`pipestitch.pose.section.fit_section`: its ellipse all ovality), and
with its circle fit (all tilt), in either mirror. Where no tilt agrees better between
consecutive frames, pair after pair (a one-sided t-test over the pairs), the pipe is
oval, and ``pipestitch run`` fits every frame again as an
oval at tilt 0 for the photometric refinement to measure (as a body-infeasible frame
starts); ``pipestitch pose`` flags its circle tilts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.errors import DatasetError
from pipestitch.geometry import PipeSection, Pose
from pipestitch.io.dataset import Dataset
from pipestitch.mosaic.photometric import contrast_strip, strip_misfit
from pipestitch.pipeline.frame_cache import blank_led
from pipestitch.pipeline.posing import PHOTOMETRIC_MIN_TILT_DEG, FramePose, strips_overlap
from pipestitch.pose.ambiguity import consistently_positive
from pipestitch.pose.fit import PoseFit
from pipestitch.pose.ring import prepare_laser_frame
from pipestitch.pose.section import fit_section

__all__ = ["OVAL_SHARE", "SAMPLE_PAIRS", "SHARES", "SIGNIFICANCE", "TiltOrOval", "tilt_or_oval"]

SAMPLE_PAIRS = 5   # pairs of consecutive frames sharing no frame, nearest the run's middle
SHARES = (0.0, 1.0)   # of each frame's circle tilt: none (an oval) and all (the circle)
# A run is taken as oval where no tilt agrees better, significantly (:func:`_oval`); shares
# between (1/4, 1/2, 3/4 were tried) decided nothing else on nine runs and cost fits.
# Starting a round pipe as an oval would cost little accuracy (the refinement measures the
# tilt from 0 and keeps no ovality: on four round pipes, half size, the circle start's
# tilt errors within 0.01 deg) but time (every frame is fitted again); reading an oval
# pipe as round costs its ovality as tilt (5 %: 18 deg; 0.6 %: 6 deg).
OVAL_SHARE = 1.0
TILT_SIGMAS = 5.0   # a frame is asked only when its circle tilt is this many sigmas
MIN_PAIRS = 3       # pairs of frames a decision for the oval needs
SIGNIFICANCE = 0.01


@dataclass(frozen=True)
class TiltOrOval:
    """What the sample said: ``oval`` (the pipe, not the probe's tilt), the best
    ``share`` of the circle tilt, the mean misfit per share, and the frames read."""

    oval: bool
    share: float
    misfits: tuple[float, ...]
    frames: tuple[int, ...]


def tilt_or_oval(dataset: Dataset, frames: Sequence[FramePose],
                 camera: CameraModel) -> TiltOrOval | None:
    """Tilt or oval, from the pose pass's circle fits (with their ring points) and the
    LED frames of a sample of them (see the module docstring).

    None when there is nothing to decide it on: no LED frames, or fewer than two pairs
    of consecutive frames whose circle tilt is clearly measured (a round pipe with a
    probe that hardly tilts; frames already started as ovals).
    """
    if not dataset.has_led:
        return None
    asked = {f.index: f for f in frames if _clear_tilt(f)}
    pairs = _disjoint_pairs([i for i in asked if i + 1 in asked
                             and strips_overlap(asked[i], asked[i + 1], dataset.odometry_mm)],
                            dataset.n_pairs / 2)
    samples = {i: _sample(dataset, asked[i]) for i in sorted({*pairs, *(i + 1 for i in pairs)})}
    strips = {i: [_strips(s, share, camera) for share in SHARES]
              for i, s in samples.items() if s is not None}
    rows = []
    for i in pairs:
        if i in strips and i + 1 in strips:
            rows.append([_pair_misfit(asked[i].fit, strips[i][n], asked[i + 1].fit,
                                      strips[i + 1][n]) for n in range(len(SHARES))])
    table = np.array([r for r in rows if np.all(np.isfinite(r))]).reshape(-1, len(SHARES))
    if len(table) < 2:
        return None
    mean = table.mean(axis=0)
    best = int(np.argmin(mean))
    return TiltOrOval(_oval(table, best), float(SHARES[best]), tuple(map(float, mean)),
                      tuple(sorted(strips)))


def _oval(table: np.ndarray, best: int) -> bool:
    """Whether the pairs' misfits (rows; columns: SHARES) say oval: a share below 1 agrees
    best on average, and each pair's gain from it over the circle's whole tilt is
    significant at ``SIGNIFICANCE`` (one-sided t-test over the pairs: the pairs are the
    replicates; on round pipes the gains scatter about zero, t = 0.7-2.2 over 5 pairs,
    on oval ones t = 7-39)."""
    if SHARES[best] >= OVAL_SHARE:
        return False
    return consistently_positive(table[:, -1] - table[:, best], SIGNIFICANCE, MIN_PAIRS)


def _disjoint_pairs(firsts: list[int], middle: float) -> list[int]:
    """Up to ``SAMPLE_PAIRS`` of the pairs (i, i + 1) starting at ``firsts``, nearest the
    run's ``middle`` and sharing no frame (each pair's gain is then its own replicate)."""
    chosen: list[int] = []
    for i in sorted(firsts, key=lambda i: abs(i + 0.5 - middle)):
        if all(abs(i - j) > 1 for j in chosen):
            chosen.append(i)
        if len(chosen) == SAMPLE_PAIRS:
            break
    return sorted(chosen)


def _clear_tilt(frame: FramePose) -> bool:
    """The frame's circle fit has a tilt well above its (known) error, and its ring points."""
    if not frame.fit.ok or frame.ring is None or not frame.fit.model.startswith("circle"):
        return False
    h = frame.fit.hypotheses[0]
    sigma = np.hypot(h.std.get("alpha", np.nan), h.std.get("beta", np.nan))
    tilt = np.rad2deg(h.pose.tilt)
    return bool(np.isfinite(sigma)
                and tilt >= max(PHOTOMETRIC_MIN_TILT_DEG, TILT_SIGMAS * np.rad2deg(sigma)))


def _sample(dataset: Dataset, frame: FramePose) -> tuple[np.ndarray, FramePose] | None:
    """A frame's grey LED frame beside its pose, or None where it shows nothing."""
    try:
        led = dataset.read_led(frame.index)
    except DatasetError:
        return None   # reported when the frame itself is processed
    return None if blank_led(dataset, frame.index, led) else (prepare_laser_frame(led), frame)


def _strips(sample: tuple[np.ndarray, FramePose], share: float,
            camera: CameraModel) -> list[np.ndarray]:
    """The frame's comparison strips with ``share`` of each mirror's tilt (one strip at
    share 0, where the mirrors coincide)."""
    led, frame = sample
    ring = frame.ring
    hypotheses = frame.fit.hypotheses if share > 0 else frame.fit.hypotheses[:1]
    out = []
    for h in hypotheses:
        if share == 1.0:   # the circle fit itself
            out.append(contrast_strip(led, camera, h.pose, PipeSection(h.radius_mm)))
            continue
        pose = Pose(share * h.pose.alpha, share * h.pose.beta, h.pose.dx_mm, h.pose.dy_mm)
        section = fit_section(ring.points_mm, pose, h.radius_mm,   # type: ignore[union-attr]
                              noise_mm=ring.noise_mm)             # type: ignore[union-attr]
        out.append(contrast_strip(led, camera, section.pose, section.section))
    return out


def _pair_misfit(before: PoseFit, first: list[np.ndarray], after: PoseFit,
                 second: list[np.ndarray]) -> float:
    """The misfit of two consecutive frames' strips (``first``, ``second``: one per
    hypothesis) in the mirror that agrees better; each of the first frame's mirrors is
    compared with the second frame's nearer one (the probe does not flip its tilt
    between frames a few millimetres apart)."""
    tilts = [np.array([h.pose.alpha, h.pose.beta]) for h in after.hypotheses]
    misfits = []
    for h, strip in zip(before.hypotheses, first, strict=False):
        near = int(np.argmin([np.linalg.norm(t - (h.pose.alpha, h.pose.beta)) for t in tilts]))
        misfits.append(strip_misfit(strip, second[min(near, len(second) - 1)]))
    return float(np.nanmin(misfits)) if np.any(np.isfinite(misfits)) else np.nan
