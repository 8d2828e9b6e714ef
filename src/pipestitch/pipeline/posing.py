"""The ``pose`` stage: every laser frame -> ring -> both hypotheses -> run-level choice.

Evidence on the mirror ambiguity: the probe envelope per frame and, where the LED
frames are present and the tilt is large enough to be measured well, photometric
consistency of consecutive LED frames; temporal continuity carries it along the run.

Frames are processed in order on a small thread pool (OpenCV and most numpy work
release the GIL). A frame that cannot be read or has no usable ring is reported and
kept as a row with its error, never dropped. Output: ``poses.csv`` per SPEC, with
extra columns after SPEC's (error, how the hypothesis was chosen, uncertainties).
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TypeVar

import numpy as np
from rich.markup import escape

from pipestitch._runtime import scratch
from pipestitch._runtime.threads import opencv_threads, ordered_map
from pipestitch.camera import CameraModel, mean_level
from pipestitch.config import ProbeConfig
from pipestitch.errors import DatasetError
from pipestitch.geometry import BodyEnvelope
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.dataset import Dataset, laser_brighter, open_dataset, swapped_note
from pipestitch.io.imu import read_imu
from pipestitch.io.mask import mask_notes, read_mask
from pipestitch.mosaic.photometric import (
    MAX_SHIFT_SHARE,
    StripPair,
    contrast_strips,
    pair_costs,
)
from pipestitch.pipeline.frame_cache import blank_led
from pipestitch.pipeline.progress import StageTimer, console, track
from pipestitch.pipeline.ring_store import RingStore, StoredRing
from pipestitch.pose.ambiguity import Choice, clearance_sigma_mm, envelope_costs, resolve_run
from pipestitch.pose.departure import MIN_EXTENT_DEG, Departure, ring_departures
from pipestitch.pose.fit import Hypothesis, LaserPlane, PoseFit, RingPoints, fit_pose
from pipestitch.pose.ring import (
    RingDetection,
    detect_ring,
    prepare_laser_frame,
    ring_band_px,
    ring_centre,
)
from pipestitch.pose.second_ring import leftover_ring
from pipestitch.pose.section import oval_at_zero_tilt

__all__ = ["OVAL_POSE_WARNING", "OVAL_TILT_WARNING", "POSE_COLUMNS", "CircleFallback",
           "FramePose", "PoseSettings", "choose", "estimate_poses", "fit_frame", "pose_sigmas",
           "report_frame_messages", "resolve_frames", "ring_search_band", "run_notes",
           "run_pose", "strips_overlap", "write_poses_csv"]

T = TypeVar("T")

POSE_COLUMNS = ("frame", "alpha_deg", "beta_deg", "dx_mm", "dy_mm", "z_mm", "roll_deg",
                "radius_mm", "ovality", "rms_px", "ambiguous", "alt_alpha_deg", "alt_beta_deg",
                "alt_dx_mm", "alt_dy_mm")
EXTRA_COLUMNS = ("error", "chosen_by", "margin", "n_points", "coverage", "model",
                 "alpha_std_deg", "beta_std_deg", "dx_std_mm", "dy_std_mm", "radius_std_mm",
                 "warning", "ovality_std", "exposure_gain")


@dataclass(frozen=True)
class CircleFallback:
    """A frame's ring circle fit that an oval start at tilt 0 replaced (without its ring
    points), its warning, and whether the run's oval decision (no body: ``oval_run``) or
    the body that could not hold the circle pose started it."""

    fit: PoseFit
    warning: str
    oval_run: bool


@dataclass(frozen=True, slots=True)
class FramePose:
    """Pose result of one frame: a fit, or the error that prevented it.

    ``strips`` (the LED frame unwrapped with both hypotheses) lives only until the
    next frame has been compared with it. ``stored_ring``: the fit's ring points once
    :func:`resolve_frames` has moved them into a :class:`RingStore` (the fit's
    ``ring`` is then None).
    """

    index: int
    fit: PoseFit
    error: str = ""
    strips: StripPair | None = None
    warning: str = ""
    stored_ring: StoredRing | RingPoints | None = field(default=None, compare=False)
    body_infeasible: bool = False   # the declared body can hold neither hypothesis
    unreadable: bool = False        # the laser frame could not be read at all
    # run's oval start replaced the ring's circle fit: that fit, for frames the LED
    # refinement then never reaches
    circle_fallback: CircleFallback | None = field(default=None, compare=False)
    # where the ring leaves the fitted section (a dent...), per hypothesis (same depth,
    # each in its own frame); empty when it follows it
    departures: tuple[Departure | None, ...] = field(default=(), compare=False)
    # the photometric comparison with the previous frame that has a fit: (its index,
    # the 2 x 2 costs), the evidence resolve_run took (None: not compared)
    compared: tuple[int, np.ndarray] | None = field(default=None, compare=False)
    # whether the laser frame is over twice as bright as its LED frame (None: not both
    # read): most of a run's so is a dataset whose frames are swapped (io/dataset.py)
    laser_brighter: bool | None = field(default=None, compare=False)
    # how far out along the rays (px) the LED frame's wall lay from the laser frame's
    # (RingDetection.led_shift_px: the probe moved between the two frames; 0: taken
    # together; NaN: the LED frame cannot tell)
    led_shift_px: float = field(default=math.nan, compare=False)

    @property
    def ring(self) -> RingPoints | StoredRing | None:
        """The frame's ring points, wherever they are kept."""
        return self.stored_ring if self.stored_ring is not None else self.fit.ring

    def with_warning(self, message: str) -> FramePose:
        """The frame with ``message`` added to its warnings ("; "-separated)."""
        return replace(self, warning="; ".join(m for m in (self.warning, message) if m))

    def without_warning(self, message: str) -> FramePose:
        """The frame with the warning ``message`` taken out of its warnings."""
        warning = self.warning
        for part in (f"; {message}", f"{message}; ", message):   # it may hold "; " itself
            warning = warning.replace(part, "")
        return replace(self, warning=warning)


INFEASIBLE_COST = 1e3   # above resolve_run's infeasible_cost: the frame is flagged infeasible
BODY_WARNING = ("the declared probe body cannot hold this pose (it would cross the wall by "
                "{clearance:.1f} mm in either mirror): ring fit kept as measured; an oval pipe "
                "or a wrong probe.toml would explain it (`pipestitch run` tests the oval)")
OVAL_TILT_WARNING = ("oval pipe: the ring alone cannot see the tilt (held at 0; `pipestitch run` "
                     "measures it from the LED frames)")

OVAL_POSE_NOTE = ("the LED frames agree best with {share:.0%} of the tilt the rings read in a "
                  "round pipe: the pipe looks oval, and the ring alone cannot tell its ovality "
                  "from tilt; `pipestitch run` measures the tilt")
OVAL_POSE_WARNING = "tilt likely the oval pipe's ovality (see the run's note)"

# Below this tilt the ring's own tilt error (tenths of a degree up to ~1°, see the
# README) makes even the true hypothesis disagree photometrically with its
# neighbour, so the comparison would be evidence about noise, not about the mirror.
PHOTOMETRIC_MIN_TILT_DEG = 1.5
# A circle fit whose every hypothesis puts the probe body this many sigmas of its
# clearance (pose.ambiguity.clearance_sigma_mm: 1.5 % of the radius at least) into the
# wall is not the declared probe in a circular pipe.
INFEASIBLE_SIGMAS = 2.0


def _photometric_strips(led: np.ndarray, fit: PoseFit, camera: CameraModel) -> StripPair | None:
    h = fit.hypotheses[0]
    tilt_deg = np.rad2deg(h.pose.tilt)
    sigma_deg = np.rad2deg(np.hypot(h.std.get("alpha", 0.0), h.std.get("beta", 0.0)))
    if tilt_deg < max(PHOTOMETRIC_MIN_TILT_DEG, 5 * sigma_deg):
        return None
    # the strips are new arrays: the grey LED frame is a temporary (pipestitch._runtime.scratch)
    grey = prepare_laser_frame(led, out=scratch.buffer("pose.led", np.shape(led)[:2], np.float32))
    return contrast_strips(grey, camera, fit)


@dataclass(frozen=True)
class PoseSettings:
    """What the per-frame fit needs from probe.toml.

    ``body`` None: probe.toml declares no body, so no envelope applies. ``oval_start``:
    a frame whose circle pose the body cannot hold starts as an oval section with the
    tilt held at 0 (``pipestitch run``, whose LED refinement then measures the tilt
    and keeps the oval only where it is significant); otherwise (``pipestitch pose``)
    the circle fit is kept and the frame flagged.
    """

    camera: CameraModel
    plane_distance_mm: float
    nominal_radius_mm: float
    body: BodyEnvelope | None
    plane_normal: np.ndarray | None = None   # laser-plane normal (probe.toml; SPEC: +z)
    ring_band_px: tuple[float, float] | None = None   # where detect_ring searches
    oval_start: bool = False
    oval_run: bool = False   # the run is an oval pipe (pipeline/tilt_or_oval.py): every frame
    # probe.toml's mask (io/mask.py: True where the camera never sees the wall): no ring
    # candidate there
    occluded: np.ndarray | None = None

    @classmethod
    def from_config(cls, cfg: ProbeConfig, *, oval_start: bool = False,
                    occluded: np.ndarray | None = None) -> PoseSettings:
        """Settings of a dataset's probe.toml (the ring searched in :func:`ring_search_band`;
        ``occluded``: its mask as read, :func:`pipestitch.io.mask.read_mask`)."""
        camera, normal = cfg.camera_model(), np.asarray(cfg.laser.plane_normal(), float)
        radius = cfg.pipe.inner_diameter_mm / 2
        body = cfg.probe.envelope()
        band = ring_search_band(camera, cfg.laser.plane_distance_mm, radius, body, normal)
        if occluded is not None:   # read-only: the ring search resamples it once (pose/ring.py)
            occluded = occluded.view()
            occluded.flags.writeable = False
        return cls(camera, cfg.laser.plane_distance_mm, radius, body, normal, band, oval_start,
                   occluded=occluded)


# The pipe a run can be in: between this many times smaller and larger than the nominal
# (wide margins for a wrong nominal, ovality and tilt).
PIPE_SIZE_FACTOR = 2.0


def ring_search_band(camera: CameraModel, plane_distance_mm: float, nominal_radius_mm: float,
                     body: BodyEnvelope | None, plane_normal: np.ndarray | None = None
                     ) -> tuple[float, float] | None:
    """Image radii where :func:`pipestitch.pose.ring.detect_ring` looks for the ring of a run.

    Where the laser plane is between half the probe body's radius (without a body: the
    axis itself, as a point probe may touch the wall) and twice the nominal pipe
    diameter from the probe axis: the wall can be neither inside the body nor further
    than the far side of a pipe twice the nominal size (wide margins for a wrong
    nominal, ovality and tilt). See :func:`pipestitch.pose.ring.ring_band_px`. None
    (the whole of every ray) when the lens sees no such plane point.
    """
    try:
        return ring_band_px(camera, plane_distance_mm, plane_normal,
                            min_wall_mm=0.0 if body is None else body.diameter_mm / 4,
                            max_wall_mm=2 * PIPE_SIZE_FACTOR * nominal_radius_mm)
    except ValueError:
        return None


def fit_frame(index: int, laser: np.ndarray, led: np.ndarray | None,
              settings: PoseSettings) -> FramePose:
    """Ring, both hypotheses and (when possible) photometric strips of one frame pair."""
    detection = detect_ring(laser, settings.camera, reflectance=led,
                            band_px=settings.ring_band_px, occluded=settings.occluded)
    fit = fit_pose(detection, settings.camera, settings.plane_distance_mm,
                   nominal_radius_mm=settings.nominal_radius_mm,
                   plane_normal=settings.plane_normal)
    fit, second = _optional(_nearer_nominal, (fit, ""), detection, fit, settings)
    if fit.ok and not _possible_size(fit, settings):   # not the wall's ring: no pose
        fit = PoseFit(False, IMPOSSIBLE_SIZE.format(radius=fit.hypotheses[0].radius_mm,
                                                    nominal=settings.nominal_radius_mm))
    warning, infeasible, fallback = _body_check(fit, settings)
    # where the ring leaves its section: on the ring's own fit (a circle fallback keeps it)
    departures = _optional(_departures, (), detection, fit, settings)
    found = [d for d in departures if d is not None]
    notes = "; ".join(m for m in (second, DEPARTURE_WARNING.format(d=found[0]) if found else "")
                      if m)
    if fallback is not None:
        fit, warning = oval_at_zero_tilt(fit, settings.camera), OVAL_TILT_WARNING
        if notes:
            fallback = replace(fallback, warning=f"{notes}; {fallback.warning}")
    strips = (_photometric_strips(led, fit, settings.camera)
              if fit.ok and led is not None else None)
    frame = FramePose(index, fit, "" if fit.ok else fit.reason, strips, warning,
                      body_infeasible=infeasible and fit.model == "circle",
                      circle_fallback=fallback, departures=departures,
                      led_shift_px=detection.led_shift_px)
    return frame.with_warning(notes)


def _body_check(fit: PoseFit, settings: PoseSettings) -> tuple[str, bool, CircleFallback | None]:
    """(warning, whether the declared body can hold neither hypothesis, the circle fit
    an oval start replaces): an oval run's frames and, with ``oval_start``, those the
    body cannot hold start as ovals at tilt 0 (:class:`PoseSettings`)."""
    if fit.ok and settings.oval_run:
        return "", False, CircleFallback(replace(fit, ring=None), OVAL_POSE_WARNING, True)
    if not fit.ok or settings.body is None:
        return "", False, None
    clearance = max(settings.body.clearance_mm(h.pose, h.pipe_section) for h in fit.hypotheses)
    if clearance >= -INFEASIBLE_SIGMAS * max(clearance_sigma_mm(h, settings.body)
                                             for h in fit.hypotheses):
        return "", False, None
    warning = BODY_WARNING.format(clearance=-clearance)
    return warning, True, (CircleFallback(replace(fit, ring=None), warning, False)
                           if settings.oval_start else None)


def _optional(step: Callable[..., T], otherwise: T, *args: object) -> T:
    """``step(*args)``, or ``otherwise`` where it fails: a check a frame's pose does not
    depend on (a second ring, a dent) never costs the frame its pose."""
    try:
        return step(*args)
    except Exception as exc:  # one frame's optional check, whatever it raises
        logging.getLogger(__name__).warning("%s failed on a frame: %r", step.__name__, exc)
        return otherwise


DEPARTURE_WARNING = ("the ring leaves the pipe section by {d.depth_mm:+.2f} mm over "
                     "{d.extent_deg:.0f} deg of its circumference (a dent, a deposit or a "
                     "bulge; profile.csv's departure columns)")


def _departures(detection: RingDetection, fit: PoseFit, settings: PoseSettings
                ) -> tuple[Departure | None, ...]:
    """:func:`pipestitch.pose.departure.ring_departures` of each hypothesis; () where the
    fit left too few rays with a candidate unexplained for one (the common case: a
    frame whose ring follows its section is not looked at twice)."""
    if not fit.ok or fit.ring is None or (
            detection.coverage - fit.coverage < MIN_EXTENT_DEG / 360.0):
        return ()
    plane = LaserPlane.of(settings.plane_distance_mm, settings.plane_normal)
    found = ring_departures(detection, [(h.pose, h.pipe_section) for h in fit.hypotheses],
                            settings.camera, plane, fit.ring.noise_mm)
    return found if any(d is not None for d in found) else ()


SECOND_RING_SHARE = 0.5   # a second ring: leftovers on at least this share of the ring's rays
SECOND_RING_WARNING = ("two rings in the laser frame (radius {kept:.2f} and {other:.2f} mm, a "
                       "reflection?): kept the one nearer the nominal {nominal:.2f} mm")


def _possible_size(fit: PoseFit, settings: PoseSettings) -> bool:
    """Whether ``fit``'s ring is that of a pipe between half and twice the nominal size
    (:data:`PIPE_SIZE_FACTOR`)."""
    ratio = fit.hypotheses[0].radius_mm / settings.nominal_radius_mm
    return 1 / PIPE_SIZE_FACTOR <= ratio <= PIPE_SIZE_FACTOR


IMPOSSIBLE_SIZE = ("the ring found is that of a pipe of radius {radius:.2f} mm, not between "
                   "half and twice the nominal {nominal:.2f} mm: not the wall's ring (a glow, a "
                   "reflection?) or probe.toml's inner_diameter_mm far off; no pose")


def _nearer_nominal(detection: RingDetection, fit: PoseFit, settings: PoseSettings
                    ) -> tuple[PoseFit, str]:
    """Of the fitted ring and a second one the candidates it left make (a reflection of
    the laser line: :mod:`pipestitch.pose.second_ring`), the one whose radius is nearer
    the nominal pipe's, and a warning naming both; ``fit`` and "" when there is no
    second ring.

    The ridge maxima under the frame's relative floor (``detection.fainter``) are looked
    at only when the fitted ring is not that of a pipe between half and twice the
    nominal size (:data:`PIPE_SIZE_FACTOR`): then something far brighter than the ring
    took the fit (a laser-lit mirror mount) and set the floor above the ring. A ring
    fitted at a possible size is not displaced by a reflection fainter than the floor
    (with a nominal that is off, the one nearer it could be the reflection)."""
    if not fit.ok or fit.ring is None:
        return fit, ""
    if _possible_size(fit, settings):
        detection = replace(detection, fainter=None)
    ring_rays = fit.coverage * detection.n_azimuths
    rest = leftover_ring(detection, fit.ring.pixels, ring_centre(settings.camera),
                         max(1, math.ceil(SECOND_RING_SHARE * ring_rays)))
    if rest is None:
        return fit, ""
    other = fit_pose(rest, settings.camera, settings.plane_distance_mm,
                     nominal_radius_mm=settings.nominal_radius_mm,
                     plane_normal=settings.plane_normal)
    if not other.ok or other.coverage < SECOND_RING_SHARE * fit.coverage:
        return fit, ""
    radii = [f.hypotheses[0].radius_mm for f in (fit, other)]
    keep = int(np.argmin([abs(r - settings.nominal_radius_mm) for r in radii]))
    return (fit, other)[keep], SECOND_RING_WARNING.format(
        kept=radii[keep], other=radii[1 - keep], nominal=settings.nominal_radius_mm)


def _load_and_fit(dataset: Dataset, index: int, settings: PoseSettings,
                  timer: StageTimer) -> FramePose:
    """One frame, never raising: a failure becomes that frame's error (SPEC)."""
    with timer("decode"):
        try:
            laser = dataset.read_laser(index)
        except DatasetError as exc:
            return FramePose(index, PoseFit(False, exc.problem),
                             f"{exc.path.name}: {exc.problem}", unreadable=True)
        led, warning = None, ""
        if dataset.has_led:
            try:
                led = dataset.read_led(index)
                if blank := blank_led(dataset, index, led):
                    raise DatasetError(dataset.led_paths[index], blank)
            except DatasetError as exc:
                # The laser frame alone still gives a pose, a little less exact.
                led = None
                warning = f"{exc.path.name}: {exc.problem}; pose from the laser frame alone"
    try:
        brighter = None if led is None else laser_brighter(mean_level(laser), mean_level(led))
        with timer("ring + pose"):
            frame = fit_frame(index, laser, led, settings)
            return replace(frame.with_warning(warning), laser_brighter=brighter)
    except Exception as exc:  # one bad frame never stops the run
        return FramePose(index, PoseFit(False, repr(exc)),
                         f"{dataset.laser_paths[index].name}: processing failed: {exc!r}")


def _ordered(dataset: Dataset, settings: PoseSettings, workers: int,
             timer: StageTimer) -> Iterator[FramePose]:
    yield from ordered_map(lambda i: _load_and_fit(dataset, i, settings, timer),
                           range(dataset.n_pairs), workers)


def run_notes(dataset: Dataset, occluded: np.ndarray | None,
              frames: Sequence[FramePose]) -> list[tuple[int, str]]:
    """The messages about the whole run (frame -1) that `pose` and `run` both give: a
    video's dropped frames and timestamp gaps (io.video), odometry.csv's warnings, a
    mask that hides the ring (:func:`pipestitch.io.mask.mask_notes`; ``occluded``: the
    mask as read) and laser frames brighter than their LED frames
    (:func:`pipestitch.io.dataset.swapped_note`)."""
    swapped = swapped_note([f.laser_brighter for f in frames if f.laser_brighter is not None])
    return ([(-1, f"video: {note}") for note in getattr(dataset, "notes", [])]
            + [(-1, f"odometry.csv: {note}") for note in dataset.odometry_notes]
            + [(-1, f"{dataset.config.probe.mask}: {note}")
               for note in mask_notes(occluded, dataset.config)]
            + ([(-1, f"frames/: {swapped}")] if swapped else []))


def strips_overlap(first: FramePose, second: FramePose,
                   odometry_mm: Mapping[int, float] | None) -> bool:
    """Whether the odometer (where it has both frames) lets two frames' comparison strips
    (:func:`pipestitch.mosaic.photometric.contrast_strips`: 0.6 to 1.8 radii ahead) share
    at least half their length."""
    if not odometry_mm or first.index not in odometry_mm or second.index not in odometry_mm:
        return True   # their correlation's peak is checked then (photometric.pair_costs)
    step = abs(odometry_mm[second.index] - odometry_mm[first.index])
    return step <= MAX_SHIFT_SHARE * 1.2 * first.fit.hypotheses[0].radius_mm


def resolve_frames(frames_in: Iterable[FramePose], body: BodyEnvelope | None,
                   rings: RingStore | None = None, *, drop_rings: bool = False,
                   odometry_mm: Mapping[int, float] | None = None
                   ) -> tuple[list[FramePose], list[Choice]]:
    """Compare consecutive frames photometrically as they come, then choose over the run.

    Strips are dropped as soon as the next frame has been compared with them, so
    memory does not grow with the run (beyond the frames the worker pool has read ahead).
    With ``rings``, each frame's ring points move into that store as the frame comes
    (:mod:`pipestitch.pipeline.ring_store`; their image pixels are dropped); with
    ``drop_rings`` they are not kept at all (and ``rings`` is not used).
    """
    frames: list[FramePose] = []
    previous: FramePose | None = None
    for frame in frames_in:
        if frame.fit.ok:
            if (previous is not None and previous.strips and frame.strips
                    and strips_overlap(previous, frame, odometry_mm)):
                frame = replace(frame, compared=(previous.index,
                                                 pair_costs(previous.strips, frame.strips)))
            previous = frame
        if (rings is not None or drop_rings) and frame.fit.ring is not None:
            frame = replace(frame, fit=replace(frame.fit, ring=None),
                            stored_ring=None if drop_rings else rings.put(frame.fit.ring))
        frames.append(replace(frame, strips=None))
    return frames, choose(frames, body)


def choose(frames: list[FramePose], body: BodyEnvelope | None,
           unlinked: Iterable[int] = ()) -> list[Choice]:
    """The run's choices (:func:`pipestitch.pose.ambiguity.resolve_run`) from the
    frames' fits, the body and their photometric comparisons (``compared``), except
    those of the frames ``unlinked``: a comparison with the previous frame that
    registration could not confirm."""
    skip = set(unlinked)
    pairwise = {f.compared[0]: f.compared[1] for f in frames
                if f.compared is not None and f.index not in skip}
    # a frame the body cannot hold in either mirror is infeasible, whatever its costs
    unary = np.array([np.full(2, INFEASIBLE_COST) if f.body_infeasible
                      else envelope_costs(f.fit, body) if f.fit.ok else np.zeros(2)
                      for f in frames])
    return resolve_run([f.fit for f in frames], unary, pairwise=pairwise)


def estimate_poses(dataset: Dataset, *, show_progress: bool = True, workers: int = 2,
                   timer: StageTimer | None = None, rings: RingStore | None = None,
                   drop_rings: bool = False,
                   settings: PoseSettings | None = None) -> tuple[list[FramePose], list[Choice]]:
    """Fit every frame and choose between the mirror hypotheses over the run (ring
    points into ``rings`` when given, or dropped: :func:`resolve_frames`; ``settings``:
    :class:`PoseSettings`, default the dataset's probe.toml's)."""
    settings = settings or PoseSettings.from_config(dataset.config)
    frames = track(_ordered(dataset, settings, workers, timer or StageTimer()), "pose",
                   total=dataset.n_pairs, enabled=show_progress)
    return resolve_frames(check_readable(frames, dataset), settings.body, rings,
                          drop_rings=drop_rings, odometry_mm=dataset.odometry_mm)


def check_readable(frames: Iterable[FramePose], dataset: Dataset) -> Iterator[FramePose]:
    """``frames`` as they come; a :class:`DatasetError` (bad input, exit 2) at the end when
    not one of the dataset's laser frames could be read: a dataset of unreadable files
    is not a run whose frames failed one by one."""
    first: FramePose | None = None
    readable = False
    for frame in frames:
        readable = readable or not frame.unreadable
        first = first or frame
        yield frame
    if first is not None and not readable:
        reader = getattr(dataset, "reader", None)   # a video's: name the video itself
        where = reader.path if reader is not None else dataset.laser_paths[first.index].parent
        raise DatasetError(where, f"not one of its {dataset.n_pairs} laser frames can be read "
                                  f"(the first: {first.error})")


def _fmt(value: float, digits: int = 6) -> str:
    return "nan" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def pose_sigmas(h: Hypothesis) -> tuple[float, float, float, float]:
    """The stated one-sigma of ``h``'s alpha, beta (deg), dx, dy (mm), as poses.csv
    writes them (nan where none)."""
    std = h.stated_std
    return (math.degrees(std.get("alpha", math.nan)), math.degrees(std.get("beta", math.nan)),
            std.get("dx_mm", math.nan), std.get("dy_mm", math.nan))


def _row(frame: FramePose, choice: Choice, z_mm: float | None,
         roll_deg: float | None) -> list[str]:
    fit = frame.fit
    z = _fmt(z_mm if z_mm is not None else math.nan)
    roll = _fmt(roll_deg if roll_deg is not None else math.nan)
    if not fit.ok or choice.chosen is None:
        # No pose: every pose value is nan, "ambiguous" does not apply (0), the error says why.
        return [str(frame.index), *["nan"] * 4, z, *["nan"] * 4, "0", *["nan"] * 4,
                frame.error or fit.reason, "none", "nan", str(fit.n_points),
                _fmt(fit.coverage, 3), fit.model, *["nan"] * 5, frame.warning, "nan"]
    h = fit.hypotheses[choice.chosen]
    alt = fit.hypotheses[1 - choice.chosen]
    d, a = h.pose.as_degrees(), alt.pose.as_degrees()
    std = h.stated_std
    return [str(frame.index), _fmt(d["alpha_deg"]), _fmt(d["beta_deg"]), _fmt(d["dx_mm"]),
            _fmt(d["dy_mm"]), z, roll,
            _fmt(h.radius_mm), _fmt(h.section.ovality if h.section else math.nan),
            _fmt(h.rms_px, 4), "1" if choice.ambiguous else "0",
            _fmt(a["alpha_deg"]), _fmt(a["beta_deg"]), _fmt(a["dx_mm"]), _fmt(a["dy_mm"]),
            "", choice.reason, _fmt(choice.margin, 2), str(fit.n_points), _fmt(fit.coverage, 3),
            fit.model, *(_fmt(s) for s in pose_sigmas(h)), _fmt(std.get("radius_mm", math.nan)),
            frame.warning, _fmt(std.get("ovality", math.nan))]


def write_poses_csv(path: Path, frames: list[FramePose], choices: list[Choice],
                    z_mm: Mapping[int, float] | None,
                    roll_deg: Mapping[int, float] | None = None,
                    gains: Mapping[int, float] | None = None) -> Path:
    """Write poses.csv (SPEC columns first, then the extra ones), atomically.

    ``z_mm`` comes from registration (``pipestitch run``) or the odometer
    (``pipestitch pose``); ``roll_deg`` from registration; ``ovality`` where an oval
    section was fitted (model ``oval/...``; the circle model cannot see it);
    ``exposure_gain`` the factor the mosaic applied to the frame's LED frame to match
    the run's exposure (``pipestitch run``). Missing values are nan.
    """
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")  # quotes messages that hold commas
    writer.writerow(POSE_COLUMNS + EXTRA_COLUMNS)
    for frame, choice in zip(frames, choices, strict=True):
        z = z_mm.get(frame.index) if z_mm else None
        roll = roll_deg.get(frame.index) if roll_deg else None
        gain = gains.get(frame.index, math.nan) if gains else math.nan
        writer.writerow([*_row(frame, choice, z, roll), _fmt(gain, 4)])
    return atomic_write_text(path, buffer.getvalue())


def report_frame_messages(messages: Iterable[tuple[int, str]], command: str = "run") -> None:
    """Print one line per (frame, message) on stderr (frame -1: the whole dataset or run,
    labelled with the ``command`` that reports it)."""
    for index, message in messages:
        where = f"frame {index:05d}" if index >= 0 else command
        console.print(f"[yellow]{where}[/]: {escape(message)}", highlight=False, soft_wrap=True)


@dataclass(frozen=True)
class PoseSummary:
    """Counts reported by the CLI."""

    n_frames: int
    n_failed: int
    n_ambiguous: int
    path: Path


def run_pose(root: str | Path, out: str | Path, *, show_progress: bool = True,
             workers: int = 2, video: Path | None = None) -> PoseSummary:
    """Estimate the pose of every frame of a dataset and write ``OUT/poses.csv``: z from
    the dataset's odometry.csv and roll from its imu.csv where they have the frame (no
    registration here), else nan."""
    # tilt_or_oval and sloping_wall read this module's FramePose
    from pipestitch.pipeline.sloping_wall import on_sloping_wall
    from pipestitch.pipeline.tilt_or_oval import tilt_or_oval

    dataset = open_dataset(root, video=video)
    notes = []
    try:
        imu = read_imu(dataset.root)   # a bad imu.csv is bad input: said before the work
        occluded = read_mask(dataset.root, dataset.config)   # as is a declared mask unfit
        # the ring points, read again only by the tilt-or-oval test, wait in a file
        with opencv_threads(1 if workers > 1 else 0), RingStore() as rings:  # _runtime/threads
            frames, choices = estimate_poses(
                dataset, show_progress=show_progress, workers=workers, rings=rings,
                settings=PoseSettings.from_config(dataset.config, occluded=occluded))
            found = tilt_or_oval(dataset, frames, dataset.config.camera_model())
    finally:
        dataset.close()   # a video's decoder
    if found is not None and found.oval:
        # No LED refinement here to measure the tilt: the circle fits stay, flagged.
        notes.append((-1, OVAL_POSE_NOTE.format(share=found.share)))
        frames = [f.with_warning(OVAL_POSE_WARNING) if f.fit.ok else f for f in frames]
    frames = on_sloping_wall(frames, choices, dataset.odometry_mm,
                             dataset.config.laser.plane_distance_mm)
    report_frame_messages(run_notes(dataset, occluded, frames) + notes
                          + [(f.index, m) for f in frames for m in (f.error, f.warning) if m],
                          command="pose")
    path = write_poses_csv(Path(out) / "poses.csv", frames, choices, dataset.odometry_mm, imu)
    return PoseSummary(len(frames), sum(1 for f in frames if not f.fit.ok),
                       sum(1 for c in choices if c.ambiguous), path)
