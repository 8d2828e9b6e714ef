"""Tilted probe or oval pipe: which one a run without a declared probe body shows.

One ring cannot tell a tilted probe in a round pipe from a less tilted one in an oval
pipe (:mod:`pipestitch.pose.section`): 5 % ovality read as a circle is ~18° of tilt.
With a probe body declared, a circle pose the body cannot hold says "oval" frame by
frame (:mod:`pipestitch.pipeline.posing`); without one, nothing in the ring does. The
LED frames do: unwrapped with the true tilt and section, consecutive frames show the
same wall up to one shift, with a wrong tilt the strip is warped and no shift explains
it (:mod:`pipestitch.mosaic.photometric`).

So a few consecutive frames from the middle of the run are fitted as circles, and for
each the tilt is scaled by a share from 0 (no tilt: the ring's ellipse is all
ovality) to 1 (the circle's tilt: no ovality), the section fitted to the ring with
that tilt held (:func:`pipestitch.pose.section.fit_section`), in either mirror. The
share whose strips agree best between consecutive frames says which: well below 1,
the run is an oval pipe, and every frame starts as an oval with the tilt held at 0
for the photometric refinement to measure (as a body-infeasible frame does).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipestitch.camera import blank_frame
from pipestitch.errors import DatasetError
from pipestitch.geometry import Pose
from pipestitch.io.dataset import Dataset
from pipestitch.mosaic.photometric import contrast_strip, strip_misfit
from pipestitch.pipeline.posing import PoseSettings, fit_frame
from pipestitch.pose.fit import Hypothesis, PoseFit
from pipestitch.pose.ring import prepare_laser_frame
from pipestitch.pose.section import fit_section

__all__ = ["OVAL_SHARE", "SAMPLE_FRAMES", "SHARES", "TiltOrOval", "tilt_or_oval"]

SAMPLE_FRAMES = 6                      # consecutive frames from the middle of the run
SHARES = np.linspace(0.0, 1.0, 5)      # of each frame's circle tilt, 0 .. 1 by 1/4
# The run stays circles only where the circle's whole tilt agrees best. Starting a
# round pipe as an oval costs little (the refinement measures the tilt from 0 and
# keeps no ovality: on round pipes without a body, half size, the same tilt errors as
# the circle start within 0.01 deg), reading an oval pipe as round costs its ovality
# as tilt (5 %: 18 deg), so the doubt goes to the oval.
OVAL_SHARE = 0.875
MIN_TILT_DEG = 1.0   # circle tilts below this read an ovality under ~0.015 %: no question


@dataclass(frozen=True)
class TiltOrOval:
    """What the sample said: ``oval`` (start every frame as an oval at tilt 0), the
    best ``share`` of the circle tilt, the misfit per share, and the frames read."""

    oval: bool
    share: float
    misfits: tuple[float, ...]
    frames: tuple[int, ...]


def tilt_or_oval(dataset: Dataset, settings: PoseSettings, *,
                 in_order: bool = False) -> TiltOrOval | None:
    """Decide tilt or oval for a run without a probe body (see the module docstring).

    The sample is taken from the middle of the run, or from its start when the frames
    are best read ``in_order`` (a video's one decoder). None when there is nothing to
    decide or nothing to decide it on: a declared body, no LED frames, fewer than two
    usable consecutive frames, or circle tilts too small for the question to matter.
    """
    if settings.body is not None or not dataset.has_led or dataset.n_pairs < 2:
        return None
    first = 0 if in_order else max(0, dataset.n_pairs // 2 - SAMPLE_FRAMES // 2)
    frames = range(first, min(dataset.n_pairs, first + SAMPLE_FRAMES))
    fitted = [_sample(dataset, i, settings) for i in frames]
    if not any(f is not None and _tilt_deg(f[1]) >= MIN_TILT_DEG for f in fitted):
        return None
    # each frame's strips at every share, made once (a frame is in two pairs)
    strips = [None if f is None else [_strips(f, share, settings) for share in SHARES]
              for f in fitted]
    totals = np.zeros(len(SHARES))
    pairs = 0
    for k in range(len(fitted) - 1):
        before, after = fitted[k], fitted[k + 1]
        if before is None or after is None:
            continue
        misfits = [_pair_misfit(before[1], strips[k][n], after[1], strips[k + 1][n])
                   for n in range(len(SHARES))]
        if np.all(np.isfinite(misfits)):
            totals += misfits
            pairs += 1
    if pairs == 0:
        return None
    best = int(np.argmin(totals))
    share = float(SHARES[best])
    return TiltOrOval(share < OVAL_SHARE, share, tuple(float(t / pairs) for t in totals),
                      tuple(frames))


def _sample(dataset: Dataset, index: int, settings: PoseSettings
            ) -> tuple[np.ndarray, PoseFit] | None:
    """A frame's grey LED frame and circle fit (with its ring points), or None."""
    try:
        laser, led = dataset.read_laser(index), dataset.read_led(index)
    except DatasetError:
        return None   # reported when the frame itself is processed
    if blank_frame(led):
        return None
    fit = fit_frame(index, laser, led, settings).fit
    if not fit.ok or fit.ring is None:
        return None
    return prepare_laser_frame(led), fit


def _tilt_deg(fit: PoseFit) -> float:
    return float(np.rad2deg(fit.hypotheses[0].pose.tilt))


def _strips(sample: tuple[np.ndarray, PoseFit], share: float,
            settings: PoseSettings) -> list[np.ndarray]:
    """The frame's comparison strips with ``share`` of each mirror's tilt (one strip at
    share 0, where the mirrors coincide)."""
    led, fit = sample
    hypotheses: Sequence[Hypothesis] = fit.hypotheses if share > 0 else fit.hypotheses[:1]
    out = []
    for h in hypotheses:
        pose = Pose(share * h.pose.alpha, share * h.pose.beta, h.pose.dx_mm, h.pose.dy_mm)
        section = fit_section(fit.ring.points_mm, pose, h.radius_mm,   # type: ignore[union-attr]
                              noise_mm=fit.ring.noise_mm)             # type: ignore[union-attr]
        out.append(contrast_strip(led, settings.camera, section.pose, section.section))
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
