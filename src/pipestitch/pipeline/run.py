"""``pipestitch run``: pose -> unwrap -> register -> mosaic -> profile -> report.

Writes into OUT (SPEC "Outputs"): poses.csv (z and roll now from registration),
mosaic.png, mosaic.ome.tif + tiles/ + viewer.html, mosaic.json, defects.csv, profile.csv and
report.html, each
atomically. Frames that fail at any stage are reported on stderr, listed in the report
and kept in poses.csv with their error; they never stop the run.
"""

from __future__ import annotations

import bisect
import itertools
import math
import shutil
import time
from collections.abc import Collection, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pipestitch import __version__
from pipestitch._runtime.memory import keep_buffers_in_heap, release_free_memory
from pipestitch._runtime.threads import opencv_threads
from pipestitch.errors import PipestitchError
from pipestitch.geometry import BodyEnvelope, Pose, WallGrid
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.dataset import Dataset, open_dataset
from pipestitch.io.imu import read_imu
from pipestitch.io.mask import read_mask
from pipestitch.io.outputs import PROFILE_COLUMNS, write_csv, write_json, write_mosaic_png
from pipestitch.measure.defects import Defect
from pipestitch.mosaic.register import Link
from pipestitch.pipeline.coding import CodedRun, code_run
from pipestitch.pipeline.frame_cache import DEFAULT_BUDGET_BYTES, CachedLedFrames
from pipestitch.pipeline.measuring import write_defects_csv
from pipestitch.pipeline.pair_timing import (
    laser_instant,
    laser_instant_poses,
    pose_vector,
    same_reference,
)
from pipestitch.pipeline.posing import (
    INFEASIBLE_SIGMAS,
    OVAL_TILT_WARNING,
    FramePose,
    PoseSettings,
    choose,
    estimate_poses,
    pose_sigmas,
    report_frame_messages,
    run_notes,
    write_poses_csv,
)
from pipestitch.pipeline.progress import StageTimer
from pipestitch.pipeline.review import write_review_page
from pipestitch.pipeline.ring_store import RingStore, StoredRing
from pipestitch.pipeline.staging import StagedOutput, check_out_folder
from pipestitch.pipeline.stitched_output import (
    PYRAMID,
    TILES,
    StreamedMosaic,
    WrittenMosaic,
    write_viewer,
)
from pipestitch.pipeline.stitching import (
    ChainLink,
    FrameView,
    LedSample,
    MosaicResult,
    MosaicSettings,
    build_mosaic,
    led_frames,
    sample_led,
)
from pipestitch.pipeline.tilt_or_oval import tilt_or_oval
from pipestitch.pose.ambiguity import Choice, clearance_sigma_mm, consistently_positive
from pipestitch.pose.fit import PARAMS, Hypothesis, RingPoints
from pipestitch.pose.section import section_free_information
from pipestitch.report.html import (
    PROBLEMS_CSV,
    TABLES,
    FrameRow,
    ReportData,
    agg_pyplot,
    draw_track_figures,
    render_report,
)
from pipestitch.report.review_page import REVIEW_NAME
from pipestitch.standards.roll_reference import imu_roll_offset

__all__ = ["RunSummary", "run_dataset"]


@dataclass(frozen=True)
class RunSummary:
    """What the CLI reports (and the benchmark reads)."""

    out: Path
    n_frames: int
    n_failed: int
    n_ambiguous: int
    n_placed: int
    seconds: float
    stage_seconds: dict[str, float] = field(default_factory=dict)
    problems: list[tuple[int, str]] = field(default_factory=list)
    mosaic: MosaicResult | None = None
    no_mosaic: str = ""        # why there is no mosaic ("" when there is one)
    mosaic_failed: bool = False  # the dataset has LED frames but no mosaic could be made

    @property
    def pairs_per_second(self) -> float:
        """End-to-end throughput (decode included)."""
        return self.n_frames / self.seconds if self.seconds > 0 else math.nan


def _chosen(frames: list[FramePose],
            choices: list[Choice]) -> Iterator[tuple[FramePose, Choice, Hypothesis]]:
    """(frame, choice, chosen hypothesis) of every frame that has a pose."""
    for frame, choice in zip(frames, choices, strict=True):
        if frame.fit.ok and choice.chosen is not None:
            yield frame, choice, frame.fit.hypotheses[choice.chosen]


def _views(frames: list[FramePose], choices: list[Choice]) -> dict[int, FrameView]:
    """The view of every frame with a pose (its ring points for the section refits)."""
    views = {}
    for frame, choice, h in _chosen(frames, choices):
        ring = _compact_ring(frame.ring)
        alt = None
        if choice.ambiguous:
            m = frame.fit.hypotheses[1 - choice.chosen]
            alt = FrameView(m.pose, m.pipe_section, information=_prior(m, ring),
                            ring=ring, oval=m.section is not None,
                            led_shift_px=frame.led_shift_px)
        views[frame.index] = FrameView(h.pose, h.pipe_section, alt, _prior(h, ring),
                                       ring=ring, oval=h.section is not None,
                                       led_shift_px=frame.led_shift_px)
    return views


def _prior(h: Hypothesis, ring: RingPoints | StoredRing | None) -> np.ndarray | None:
    """The refinement's prior of a frame's pose: for a circle fit, what its ring says
    with the section left free (:func:`pipestitch.pose.section.section_free_information`;
    the ring's own information assumes a round pipe, and would hold a slightly oval
    pipe's ovality as tilt against the LED frames), else the fit's own."""
    if h.section is not None or ring is None:
        return h.information
    return section_free_information(ring.points_mm, h.pose, h.radius_mm)


def _compact_ring(ring: RingPoints | StoredRing | None) -> RingPoints | StoredRing | None:
    """The ring points the section refits read (``uv``), without their image pixels:
    they are kept until the last refit (~6 kB a frame instead of ~12; a stored ring,
    :mod:`pipestitch.pipeline.ring_store`, is a handle of a few dozen bytes)."""
    if ring is None or isinstance(ring, StoredRing):
        return ring
    return ring.without_pixels()


def _without_rings(frames: list[FramePose]) -> list[FramePose]:
    """Frames whose fits no longer carry their ring points (nothing after the views
    reads them)."""
    return [replace(f, fit=replace(f.fit, ring=None), stored_ring=None)
            if f.ring is not None else f for f in frames]


RELATIVE_MIRROR = ("pose ambiguous: mirror chosen by registration against its neighbours only, "
                   "whose own mirrors nothing decided (this stretch may be on its mirror as a "
                   "whole)")
AMBIGUOUS = {
    "registration-relative": RELATIVE_MIRROR,
    "photometric-unconfirmed": "pose ambiguous: its mirror was chosen by comparing LED frames "
                               "that registration found no common wall between",
}


def _unconfirmed_comparisons(frames: list[FramePose], choices: list[Choice],
                             result: MosaicResult, body: BodyEnvelope | None) -> list[Choice]:
    """Choices made again without the photometric comparisons of consecutive frames
    that registration found no link between (their strips share too little wall: a
    step too large for the comparison, which without an odometer cannot tell). A frame
    registration took (in ``result.views``: unwrapped, perhaps refined and stitched with
    its hypothesis) keeps it and is flagged where the choice changes
    (``photometric-unconfirmed``); any other takes the new choice."""
    linked = {(min(ln.i, ln.j), max(ln.i, ln.j)) for ln in result.links}
    unlinked = [f.index for f in frames
                if f.compared is not None and (f.compared[0], f.index) not in linked]
    if not unlinked:
        return choices
    out = []
    again = choose(frames, body, unlinked)
    for frame, old, new in zip(frames, choices, again, strict=True):
        if (new.chosen, new.ambiguous) != (old.chosen, old.ambiguous):
            old = (Choice(old.chosen, True, "photometric-unconfirmed", new.margin)
                   if frame.index in result.views else new)
        out.append(old)
    return out


def _apply_switches(choices: list[Choice], switched: dict[int, bool],
                    links: Sequence[Link], chains: Sequence[ChainLink] = ()) -> list[Choice]:
    """Choices after registration's photometric decision on the ambiguous frames.

    Registration compares a frame's two unwraps with the earlier frames it links to, as
    they were chosen: a decision is only as absolute as they are. Two consecutive frames
    on their wrong mirrors warp the wall alike where their poses are alike, so a stretch
    of ambiguous frames decided only against each other may be one consistent choice of
    two. A decision counts (``registration``, not flagged) when the frame links back to
    a frame whose mirror the pose step decided (body, photometric comparison,
    continuity) or to one such decision in turn; or (``registration-chain``) when its
    stretch, registered frame to frame as chosen, correlates better than the same
    stretch all mirrored, link after link (:func:`_chain_decided`: where the pose
    changes along the stretch, only the right chain unwraps every frame undistorted).
    Otherwise the frame stays flagged (``registration-relative``)."""
    earlier: dict[int, set[int]] = {}
    for ln in links:
        earlier.setdefault(max(ln.i, ln.j), set()).add(min(ln.i, ln.j))
    anchored = {k for k, c in enumerate(choices) if not c.ambiguous and c.chosen is not None}
    for k in sorted(switched):
        if earlier.get(k, set()) & anchored:
            anchored.add(k)
    by_chain = _chain_decided(sorted(set(switched) - anchored), switched, chains)
    out = []
    for k, c in enumerate(choices):
        if k in switched and c.chosen is not None:
            chosen = 1 - c.chosen if switched[k] else c.chosen
            c = (Choice(chosen, False, "registration", c.margin) if k in anchored
                 else Choice(chosen, False, "registration-chain", c.margin) if k in by_chain
                 else Choice(chosen, True, "registration-relative", c.margin))
        out.append(c)
    return out


def _chain_decided(relative: list[int], switched: dict[int, bool],
                   chains: Sequence[ChainLink]) -> set[int]:
    """The frames of ``relative`` (decided by registration against ambiguous frames only)
    whose stretch of consecutive such frames, with the frame before it, registered
    better as chosen than mirrored link after link: the gains of its consecutive
    :class:`~pipestitch.pipeline.stitching.ChainLink` (chosen minus mirrored response)
    positive at 1 % (one-sided t-test, at least 3 links). Only links measured with both
    frames on their final hypotheses count."""
    valid = {(c.first, c.second): c.chosen - c.mirrored for c in chains
             if c.switched_first == switched.get(c.first, False)
             and c.switched_second == switched.get(c.second, False)}
    decided: set[int] = set()
    stretch: list[int] = []
    for k in [*relative, None]:
        if k is not None and (not stretch or k == stretch[-1] + 1):
            stretch.append(k)
            continue
        if stretch:
            frames = [stretch[0] - 1, *stretch]
            gains = [valid[a, b] for a, b in itertools.pairwise(frames) if (a, b) in valid]
            if consistently_positive(gains, CHAIN_SIGNIFICANCE, MIN_CHAIN_LINKS):
                decided.update(stretch)
        stretch = [] if k is None else [k]
    return decided


CHAIN_SIGNIFICANCE = 0.01   # a stretch registered as chosen beats its mirror at this level
MIN_CHAIN_LINKS = 3


def _with_refined(frames: list[FramePose], choices: list[Choice],
                  views: dict[int, FrameView], share: float) -> list[FramePose]:
    """Frames whose chosen hypothesis carries the photometrically refined pose (at the
    laser frame's instant where the LED frames were taken ``share`` of a step later or
    earlier, with the sigma that holds what taking it there leaves:
    :func:`pipestitch.pipeline.pair_timing.laser_instant_poses`)."""
    led = {i: pose_vector(v.pose) for i, v in views.items() if v.refined}
    stated = {f.index: _refined_std(views[f.index], h.stated_std)
              for f, _, h in _chosen(frames, choices) if f.index in led}
    # only the poses that are the LED frames' move (not a frame whose refinement kept
    # its ring's pose, nor one whose ring had no neighbour to move its prior), and only
    # they say how the LED frames' track bends
    moved = {i for i in led if views[i].led_delta is not None}
    back, back_std = laser_instant_poses(
        led, {i: np.array([stated.get(i, {}).get(k, math.nan) for k in PARAMS[:4]])
              for i in led}, share, track=moved)
    out = []
    for frame, choice in zip(frames, choices, strict=True):
        view = views.get(frame.index)
        if view is not None and view.refined and choice.chosen is not None:
            hyps = list(frame.fit.hypotheses)
            h = hyps[choice.chosen]
            i = frame.index
            std = stated.get(i, {})
            if i in moved and std and np.all(np.isfinite(back_std[i])):
                std = dict(zip(PARAMS[:4], map(float, back_std[i]), strict=True))
            h = replace(h, pose=Pose(*(back[i] if i in moved else led[i])),
                        std_override=std)
            model = frame.fit.model
            if view.measured is not None:  # the section fitted at the refined tilt
                m = view.measured
                h = replace(h, radius_mm=m.section.mean_radius_mm, section=m.section,
                            std={**h.std, "radius_mm": m.radius_std_mm,
                                 "ovality": m.ovality_std})
                # oval: the frame was unwrapped as an oval (pose offset from that fit);
                # circle: its ovality is measured but not significant (pose as refined)
                model = "oval/refined-tilt" if view.oval else "circle/refined-tilt"
            hyps[choice.chosen] = h
            # an oval started at tilt 0 has its tilt measured now: that warning is done
            frame = replace(frame, fit=replace(frame.fit, hypotheses=tuple(hyps), model=model)
                            ).without_warning(OVAL_TILT_WARNING)
        out.append(frame)
    return out


LED_INSTANT_NOTE = ("frames/: the LED frames were taken {share:.2f} of a step ({mm:.2f} mm) "
                    "{when} their laser frames (the probe moves between the two frames of a "
                    "pair; {told}): each pose refined at its LED frame's instant, "
                    "stated at its laser frame's")


def _led_instant_note(result: MosaicResult | None) -> list[tuple[int, str]]:
    """The run's message (frame -1) saying when the LED frames were taken, where the
    refinement measured that they were not taken with their laser frames."""
    share = result.led_share if result is not None else 0.0
    if share == 0.0:
        return []
    z = [v for v in _finite(result.positions.z_mm).values()]
    step = float(np.median(np.abs(np.diff(z)))) if len(z) > 1 else math.nan
    return [(-1, LED_INSTANT_NOTE.format(share=abs(share), mm=abs(share) * step,
                                         when="after" if share > 0 else "before",
                                         told=result.led_share_told))]


def _laser_instant_positions(result: MosaicResult, odometry_mm: Mapping[int, float] | None,
                             imu: Mapping[int, float]
                             ) -> tuple[dict[int, float], dict[int, float]]:
    """The placed frames' z and roll at their laser frames' instants
    (:func:`pipestitch.pipeline.pair_timing.laser_instant`), with the references the
    solve gave them: z the odometer's (median offset 0) or the first frame at 0, roll the
    IMU's or as registration had it."""
    share, positions = result.led_share, result.positions
    z, roll = _finite(positions.z_mm), _finite(positions.roll_deg)
    if share == 0.0:
        return z, roll
    z_back = same_reference(laser_instant(z, share, average=False), z, odometry_mm,
                            positions.odometer_scale)
    roll_back = laser_instant(roll, share, average=False)
    found = imu_roll_offset(roll_back, imu) if positions.roll_reference == "imu" else None
    roll_back = ({i: r + found[0] for i, r in roll_back.items()} if found is not None
                 else same_reference(roll_back, roll))
    return z_back, roll_back


def _refined_std(view: FrameView, ring_std: Mapping[str, float]) -> dict[str, float]:
    """The refined pose's one-sigma uncertainties (keys of ``Hypothesis.std``): the
    refinement's (its covariance) where they are smaller than the ring's stated ones.

    The refinement's prior leaves the pipe's section free (an oval would bias a ring
    taken as round), so where the LED frames add little (few patches between few
    frames) its posterior is about that weak prior's, wider than what the ring says of
    a round pipe; the ring's is then stated, as for a pose from the ring alone. Empty
    without a covariance.
    """
    if view.covariance is None or not np.all(np.isfinite(view.covariance)):
        return {}
    sigma = np.sqrt(np.clip(np.diag(view.covariance), 0.0, None))
    return {k: min(float(s), ring_std.get(k, math.inf))
            for k, s in zip(PARAMS[:4], sigma, strict=True)}


def _still_infeasible(frames: list[FramePose], choices: list[Choice],
                      body: BodyEnvelope | None, ring_frames: list[FramePose]
                      ) -> tuple[list[FramePose], list[Choice]]:
    """Refined poses the declared body cannot hold, flagged (SPEC: the reason in
    ``warning``; SPEC's columns keep the ring's fit). A frame the body could not hold in
    either mirror (started as an oval) whose refined pose and section it still cannot
    hold: the body is wrong for it, and its circle fit is kept. A frame whose ring pose
    it held: the refinement went astray (the LED frames share too little wall, a texture
    that misleads the patch shifts), and the ring's pose (``ring_frames``) is kept."""
    if body is None:
        return frames, choices
    out_frames, out_choices = [], []
    for k, (frame, choice) in enumerate(zip(frames, choices, strict=True)):
        if choice.chosen is not None and frame.fit.ok:
            h = frame.fit.hypotheses[choice.chosen]
            clearance = body.clearance_mm(h.pose, h.pipe_section)
            if clearance < -INFEASIBLE_SIGMAS * clearance_sigma_mm(h, body):
                started_oval = frame.circle_fallback is not None
                warning = (REFINED_INFEASIBLE if started_oval
                           else REFINEMENT_REJECTED).format(clearance=-clearance)
                # SPEC's columns keep the ring's fit: the circle one of a frame started as
                # an oval, the ring's pose of one the refinement moved
                kept = (replace(frame, fit=frame.circle_fallback.fit, circle_fallback=None)
                        if started_oval else ring_frames[k])
                frame = kept.with_warning(warning)
                choice = (Choice(0, True, "infeasible", 0.0) if started_oval
                          else Choice(choice.chosen, True, "refinement-rejected", choice.margin))
        out_frames.append(frame)
        out_choices.append(choice)
    return out_frames, out_choices


REFINEMENT_REJECTED = ("the LED refinement moved this pose where the declared probe body "
                       "cannot be (crossing the wall by {clearance:.1f} mm): the ring's pose is "
                       "kept, the mosaic near this frame is doubtful")


REFINED_INFEASIBLE = ("the declared probe body cannot hold the pose and section measured "
                      "from the LED frames either (it would cross the wall by {clearance:.1f} "
                      "mm): check probe.toml's [probe] body and its [laser] plane (distance "
                      "and normal)")


def _unrefined_ovals_back(frames: list[FramePose], choices: list[Choice],
                          views: dict[int, FrameView]
                          ) -> tuple[list[FramePose], list[Choice]]:
    """Frames started as an oval at tilt 0 (the body could not hold their circle pose) that
    the LED refinement never reached get their ring's circle fit back, flagged: the
    tilt-0 start is a guess that only the refinement turns into a measurement (SPEC)."""
    out_frames, out_choices = [], []
    for frame, choice in zip(frames, choices, strict=True):
        view = views.get(frame.index)
        if frame.circle_fallback is not None and not (view is not None and view.refined):
            back = frame.circle_fallback
            oval_run = back.oval_run   # no body: the run's oval decision
            frame = replace(frame, fit=back.fit, warning=back.warning,
                            body_infeasible=not oval_run, circle_fallback=None)
            choice = Choice(0, True, "oval-run" if oval_run else "infeasible", 0.0)
        out_frames.append(frame)
        out_choices.append(choice)
    return out_frames, out_choices


UNWRAP_RADIUS_WARNING = ("part of this frame's strip lies where the wall's radius (from the "
                         "rings there) differs from its own ring's by up to {off:+.1f} %: "
                         "the strip, its links and its z are scaled by up to about as much "
                         "(each strip is unwrapped onto its ring's section)")


def _wall_off_the_ring(frames: list[FramePose], choices: list[Choice], z: dict[int, float],
                       window_mm: tuple[float, float], plane_distance_mm: float,
                       tolerance_pct: float, profiled: Collection[int]) -> list[FramePose]:
    """Frames whose strip (``window_mm`` about their camera's z) reaches wall whose radius,
    measured by the rings of the frames there, differs from their own ring's by more
    than ``tolerance_pct`` % (a reducer, a long dent), warned unless their strip was
    unwrapped onto that wall (``profiled``: :mod:`pipestitch.mosaic.wall_profile`);
    unwrapped onto their own ring's section, their axial scale, the registration's steps
    and z are off by about as much there."""
    posed = [(f.index, h.radius_mm) for f, _, h in _chosen(frames, choices)
             if math.isfinite(z.get(f.index, math.nan))]
    if len(posed) < 2:
        return frames
    index, radius = np.array(posed).T
    ring_z = np.array([z[int(i)] for i in index]) + plane_distance_mm
    worst: dict[int, float] = {}
    for i, own in posed:
        if i in profiled:
            continue
        there = radius[(ring_z >= z[i] + window_mm[0]) & (ring_z <= z[i] + window_mm[1])]
        off = 100.0 * (there - own) / own
        if off.size and np.max(np.abs(off)) > tolerance_pct:
            worst[i] = float(off[np.argmax(np.abs(off))])
    return [f.with_warning(UNWRAP_RADIUS_WARNING.format(off=worst[f.index]))
            if f.index in worst else f for f in frames]


def _profile_rows(frames: list[FramePose], choices: list[Choice], z: dict[int, float],
                  roll: dict[int, float], plane_distance_mm: float, nominal_mm: float,
                  tolerance_pct: float) -> list[list[object]]:
    """Diameter and ovality per frame from the ring.

    With an oval section fitted (model ``oval/...``) the min/max radius are its
    semi-axes and ovality (Dmax - Dmin)/Dmean (SPEC); with the circle model alone
    (``pipestitch pose`` on a round pipe, frames not refined) min = max and the
    ovality is nan: a ring alone cannot tell ovality from tilt. z is the ring's
    axial position: the camera's z plus the laser plane distance;
    ``within_tolerance`` is 1 when the mean diameter is within ``tolerance_pct`` %
    of nominal; ``major_axis_theta_deg`` is the mosaic theta (0-180) of the oval's
    longer axis (the frame's own angle turned by its roll; nan without an oval fit or
    a place in the mosaic). Where the ring leaves the section over part of its
    circumference (a dent: :mod:`pipestitch.pose.departure`), ``departure_mm`` is its
    signed radial extreme (negative inward) at mosaic theta ``departure_theta_deg``
    over ``departure_extent_deg``, and min/max radius include it; nan elsewhere.
    """
    rows: list[list[object]] = []
    for frame, choice, h in _chosen(frames, choices):
        sec, std = h.pipe_section, h.stated_std
        lo, hi = sorted((sec.a_mm, sec.b_mm))
        major = math.degrees(sec.angle) + (0.0 if sec.a_mm >= sec.b_mm else 90.0)
        turn = roll.get(frame.index, math.nan)
        axis = (major + turn) % 180.0 if h.section is not None else math.nan
        dep = frame.departures[choice.chosen] if frame.departures else None
        departure = ([math.nan] * 3 if dep is None else
                     [dep.depth_mm, (dep.theta_deg + turn) % 360.0, dep.extent_deg])
        if dep is not None:
            lo, hi = min(lo, dep.min_radius_mm), max(hi, dep.max_radius_mm)
        rows.append([frame.index, z.get(frame.index, math.nan) + plane_distance_mm,
                     2 * h.radius_mm, sec.ovality if h.section is not None else math.nan,
                     lo, hi, 2 * std.get("radius_mm", math.nan), frame.fit.model,
                     int(abs(2 * h.radius_mm - nominal_mm) <= tolerance_pct / 100 * nominal_mm),
                     std.get("ovality", math.nan), axis, *departure])
    return rows


def _frame_rows(frames: list[FramePose], choices: list[Choice],
                z: dict[int, float]) -> list[FrameRow]:
    rows = []
    for frame, choice, h in _chosen(frames, choices):
        d = h.pose.as_degrees()
        rows.append(FrameRow(frame.index, z.get(frame.index, math.nan), d["alpha_deg"],
                             d["beta_deg"], d["dx_mm"], d["dy_mm"], 2 * h.radius_mm,
                             choice.ambiguous, choice.reason, pose_sigmas(h)))
    return rows


def _grid_json(g: WallGrid, radius_mm: float) -> dict[str, float | int]:
    return {"mm_per_px_axial": g.mm_per_px_axial, "deg_per_px": g.deg_per_px, "z0_mm": g.z0_mm,
            "n_rows": g.n_rows, "n_cols": g.n_cols,
            "mm_per_px_circumferential": 2 * math.pi * radius_mm / g.n_rows}


IMU_THETA = ("imu: theta of the pipe frame whose +y points down (imu.csv's roll, its offset "
             "to registration's the circular mean over the frames); the crown at 270 deg")


def _mosaic_json(result: MosaicResult, written: WrittenMosaic, dataset: Dataset,
                 settings: MosaicSettings) -> dict[str, object]:
    """mosaic.json: the scale of mosaic.png (SPEC) and of the full-resolution mosaic."""
    return {
        **_grid_json(written.overview_grid, result.radius_mm), "radius_mm": result.radius_mm,
        "overview_factor": written.factor,
        "full_resolution": {"file": PYRAMID, **_grid_json(written.grid, result.radius_mm)},
        "theta_reference": (IMU_THETA if result.positions.roll_reference == "imu" else
                            "relative: theta 0 is the roll of the first frame of the largest "
                            "group linked by registration"),
        "roll_interpolated_frames": result.positions.roll_guessed,
        "z_reference": ("odometer (median offset), scale fitted"
                        if dataset.odometry_mm else "camera of the first placed frame at 0"),
        "odometer_scale": result.positions.odometer_scale,
        "intensity_scale": written.intensity_scale, "no_data_value": 0, "unwrap": settings.mode,
        "frames_placed": result.placed, "frames_skipped": sorted(result.skipped),
        "window_mm": list(result.window_mm), "pipestitch_version": __version__,
    }


def _problems(frames: list[FramePose], result: MosaicResult | None, choices: list[Choice],
              no_mosaic: str) -> list[tuple[int, str]]:
    """(frame, message) of everything that went wrong; frame -1 for the whole run."""
    problems = [(f.index, m) for f in frames for m in (f.error, f.warning) if m]
    if no_mosaic:
        problems.append((-1, no_mosaic))
    if result is not None:
        problems += [(j, f"{src} from frame {i:05d} rejected by the global solve")
                     for i, j, src in result.positions.outliers]
        problems += [(k, "roll interpolated (not linked to the roll reference by registration)")
                     for k in result.positions.roll_guessed]
    problems += [(c_i, AMBIGUOUS.get(c.reason, "pose ambiguous (mirror hypothesis not ruled out)"))
                 for c_i, c in enumerate(choices) if c.ambiguous]
    if result is not None:
        problems += [(i, f"not in the mosaic: {m}") for i, m in sorted(result.skipped.items())]
    return sorted(problems)


def run_dataset(root: str | Path, out: str | Path, *, settings: MosaicSettings | None = None,
                show_progress: bool = True, tolerance_pct: float = 1.0,
                video: Path | None = None, crown_deg: float | None = None,
                led_cache_mb: float = DEFAULT_BUDGET_BYTES / 2**20) -> RunSummary:
    """Process a dataset end to end and write every output into ``out``.

    ``tolerance_pct``: profile.csv flags diameters further than this from nominal.
    ``crown_deg``: mosaic theta of 12 o'clock for the clock positions (the standards
    stage; default: imu.csv, else a detected invert, else relative).
    ``led_cache_mb``: the decoded LED frames are kept in memory when the whole run fits
    this (0: never), else in a spill file in ``out`` (pipeline/frame_cache.py).
    """
    settings = settings or MosaicSettings()
    out = Path(out)
    check_out_folder(Path(root), out)
    dataset = CachedLedFrames(open_dataset(root, video=video),
                              budget_bytes=int(led_cache_mb * 2**20), spill_dir=out)
    try:
        read_imu(dataset.root)   # a bad imu.csv or mask is bad input: say so before the work
        declared = read_mask(dataset.root, dataset.config)
        keep_buffers_in_heap()   # per-frame buffers reused, not mapped anew (_runtime/memory.py)
        # The frames are spread over the workers: OpenCV splitting each call again
        # costs more than it gains (_runtime/threads.py).
        # The ring points wait for the section refits in a temporary file, not in
        # memory (pipeline/ring_store.py). The outputs are staged and replace the
        # previous run's only when this one succeeds (pipeline/staging.py).
        with (opencv_threads(1 if settings.workers > 1 else 0), RingStore() as rings,
              StagedOutput(out) as staged):
            summary = _run(dataset, staged.path, settings, show_progress, tolerance_pct,
                           crown_deg, rings, declared, in_order=video is not None)
            if summary.mosaic_failed:
                kept = staged.keep()
                note = (f"the previous outputs in {out} are left as they were; this run's "
                        f"are in {kept}")
                report_frame_messages([(-1, note)])
                return replace(summary, problems=[*summary.problems, (-1, note)])
            staged.commit()
            return replace(summary, out=out)
    finally:
        dataset.close()   # a video's decoder
        release_free_memory()   # the run's freed heap back to the system, for the caller


def _occluders_ahead(pool: ThreadPoolExecutor, dataset: Dataset, settings: MosaicSettings,
                     timer: StageTimer, in_order: bool, declared: np.ndarray | None,
                     ) -> Future[LedSample] | None:
    """The occluder mask (probe.toml's when it names one: ``declared``, as read), the
    sensor's stuck pixels and the LED frames' noise model (:func:`sample_led`), found
    from the LED frames while the poses are fitted (they need no pose, and the pose
    pass's two workers leave them a share of the machine instead of a stage of their own
    on one core afterwards).

    None where there is nothing to find or the mosaic stage finds it itself: no LED
    frames, or frames read ``in_order`` (a video's one decoder: reading frames spread
    along the run would make the pose pass seek back each time).
    """
    if in_order or not dataset.has_led:
        return None
    frames = led_frames(dataset)
    if not frames:
        return None
    return pool.submit(sample_led, dataset, frames, settings.reference_frames, timer,
                       settings.workers, occluded=declared)


def _mosaic_or_reason(dataset: Dataset, views: dict[int, FrameView], settings: MosaicSettings,
                      timer: StageTimer, show_progress: bool, out: Path,
                      declared: np.ndarray | None, occluders: Future[LedSample] | None,
                      ) -> tuple[MosaicResult | None, WrittenMosaic | None, str]:
    """The mosaic, streamed into OUT's pyramid, overview and defects as it is stitched;
    or None and why not (the poses are worth writing all the same). The occluder mask:
    probe.toml's (``declared``), else the one being found with the frames' noise model
    (``occluders``, :func:`_occluders_ahead`), else the mosaic stage's own."""
    if not views:
        return None, None, "no mosaic: no frame has a pose"
    if not dataset.has_led:
        return None, None, "the dataset has no LED frames: no mosaic"
    try:
        occluded, noise, defects = ((declared, None, ()) if occluders is None
                                    else occluders.result())
        with StreamedMosaic(out, timer) as sink:
            result = build_mosaic(dataset, views, settings, timer=timer,
                                  show_progress=show_progress, sink=sink,
                                  occluded=occluded, noise=noise, defects=defects)
            return result, sink.finish(), ""
    except PipestitchError as exc:
        return None, None, f"no mosaic: {exc}"
    except (ValueError, MemoryError) as exc:
        # e.g. a --mm-per-px at which no wall is resolved, or a canvas too large
        return None, None, f"no mosaic: {exc!r}"


def _run(dataset: Dataset, out: Path, settings: MosaicSettings, show_progress: bool,
         tolerance_pct: float, crown_deg: float | None, rings: RingStore,
         declared: np.ndarray | None, *, in_order: bool = False) -> RunSummary:
    start = time.perf_counter()
    timer = StageTimer()
    # only the section refits of the photometric refinement read the ring points again
    refits = dataset.has_led and settings.refine_rounds > 0
    ahead = ThreadPoolExecutor(max_workers=1)
    try:
        occluders = _occluders_ahead(ahead, dataset, settings, timer, in_order, declared)
        # The report's plotting library, imported while the poses are fitted: a third of
        # a second of the run's last stretch on one core otherwise.
        ahead.submit(agg_pyplot)
        frames, choices = _poses(dataset, refits, show_progress, settings.workers, timer,
                                 rings, declared)
        if rings.problem:
            report_frame_messages([(-1, rings.problem)])
        views = _views(frames, choices)
        frames = _without_rings(frames)
        out.mkdir(parents=True, exist_ok=True)
        release_free_memory()   # each pass starts from what is live (_runtime/memory.py)
        result, written, no_mosaic = _mosaic_or_reason(dataset, views, settings, timer,
                                                       show_progress, out, declared,
                                                       occluders)
        if isinstance(dataset, CachedLedFrames):
            # The stitch was the last pass to read the LED frames: their memory goes
            # back with the trim below, and the spill file (up to gigabytes) is closed
            # beside the outputs' writing, not after it (~0.2 s).
            dataset.release(close_in_background=True)
    finally:
        # a run that stops (Ctrl-C, an error, no pose) does not wait for a mask it drops
        ahead.shutdown(wait=False, cancel_futures=True)
    release_free_memory()
    imu = read_imu(dataset.root) or {}
    if result is not None:
        choices = _unconfirmed_comparisons(frames, choices, result,
                                           dataset.config.probe.envelope())
        choices = _apply_switches(choices, result.switched, result.links, result.chains)
        ring_frames = frames
        frames = _with_refined(frames, choices, result.views, result.led_share)
        frames, choices = _still_infeasible(frames, choices, dataset.config.probe.envelope(),
                                            ring_frames)
        z, roll = _laser_instant_positions(result, dataset.odometry_mm, imu)
        z = _with_odometer(z, dataset.odometry_mm, result.positions.odometer_scale)
        if result.positions.roll_reference == "imu":   # frames not placed: the IMU's own
            roll = {**imu, **roll}
    else:
        # Poses and the profile still; z from the odometer, roll from the IMU (as pose).
        z, roll = dict(dataset.odometry_mm or {}), dict(imu)
    frames, choices = _unrefined_ovals_back(frames, choices,
                                            result.views if result is not None else {})
    if result is not None:
        frames = _wall_off_the_ring(frames, choices, z, result.window_mm,
                                    dataset.config.laser.plane_distance_mm, tolerance_pct,
                                    {i for i, v in result.views.items() if v.profile is not None})
    rows = _frame_rows(frames, choices, z)
    # Two threads: the plots (one thread at a time draws with pyplot) beside the PNG
    # encoding of mosaic.png and then the review page.
    tail = ThreadPoolExecutor(max_workers=2)
    try:
        # the pose and profile plots need only the rows: drawn while the outputs are written
        track_figures = tail.submit(draw_track_figures, ReportData(
            "", None, 0.0, 1.0, 1.0, dataset.config.pipe.inner_diameter_mm, rows,
            tolerance_pct=tolerance_pct))
        # Defects were measured while the mosaic was written, on the 8-bit values that
        # mosaic.ome.tif holds, so `pipestitch measure OUT` finds exactly the same ones.
        defects: list[Defect] = written.defects if written is not None else []
        with timer("write"):
            # mosaic.png is encoded in the thread (the stages below use the overview
            # in memory); png.result() below waits for it and raises its error
            png = _write_mosaic(out, result, written, dataset, settings, tail)
        with timer("write"):
            if result is not None:
                write_defects_csv(out / "defects.csv", defects)
            write_poses_csv(out / "poses.csv", frames, choices, z, roll,
                            result.gains if result is not None else None)
            write_csv(out / "profile.csv", PROFILE_COLUMNS,
                      _profile_rows(frames, choices, z, roll,
                                    dataset.config.laser.plane_distance_mm,
                                    dataset.config.pipe.inner_diameter_mm, tolerance_pct))
        problems = _problems(frames, result, choices, no_mosaic)
        problems = run_notes(dataset, declared, frames) + _led_instant_note(result) + problems
        with timer("standards"):
            coded = _coded(out, dataset, crown_deg, problems,
                           written.overview if written is not None else None)
        report_frame_messages(problems)
        summary = RunSummary(out, len(frames), sum(1 for f in frames if not f.fit.ok),
                             sum(1 for c in choices if c.ambiguous),
                             len(result.placed) if result else 0, time.perf_counter() - start,
                             dict(timer.seconds), problems, result, no_mosaic,
                             not views or (dataset.has_led and result is None))
        with timer("report"):
            data = _report_data(dataset, rows, written, result, summary)
            data.drawn = track_figures.result()
            data.defects = coded.defects if coded is not None and result is not None else defects
            data.tolerance_pct = tolerance_pct
            data.standards = coded.report_view() if coded is not None else None
            _write_report(out, data, result is not None, tail)
        if png is not None:
            png.result()
        return summary
    except BaseException:
        # a run that stops does not wait for queued work it drops (the one running ends)
        tail.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        tail.shutdown(wait=True)


def _write_report(out: Path, data: ReportData, with_mosaic: bool,
                  pool: ThreadPoolExecutor) -> None:
    """report.html, the problems it lists as problems.csv beside it, and review.html
    (written by ``pool`` while the report is rendered: it reads the outputs written
    before, not the report; its error, if any, is raised here)."""
    write_csv(out / PROBLEMS_CSV, ("frame", "problem"), data.problems)
    review = pool.submit(write_review_page, out, data.mosaic) if with_mosaic else None
    data.review_href = REVIEW_NAME if with_mosaic else None
    data.tables = [name for name, _ in TABLES if (out / name).is_file()]
    atomic_write_text(out / "report.html", render_report(data))
    if review is not None:
        review.result()


def _coded(out: Path, dataset: Dataset, crown_deg: float | None,
           problems: list[tuple[int, str]], overview: np.ndarray | None) -> CodedRun | None:
    """The standards stage; a failure there is reported, and the report still written."""
    try:
        return code_run(out, dataset=dataset.root, crown_deg=crown_deg,
                        nominal_diameter_mm=dataset.config.pipe.inner_diameter_mm,
                        overview=overview)
    except Exception as exc:  # e.g. a malformed row a user kept in observations.csv
        problems.append((-1, f"observations not coded: {exc}"))
        return None


def _poses(dataset: Dataset, refits: bool, show_progress: bool, workers: int,
           timer: StageTimer, rings: RingStore, declared: np.ndarray | None,
           ) -> tuple[list[FramePose], list[Choice]]:
    """The pose pass (no ring candidate where probe.toml's mask, ``declared``, says the
    camera never sees the wall). Frames the declared body cannot hold start as ovals
    when the LED refinement follows (``refits``); when the LED frames say the pipe is
    oval rather than the probe tilted (:func:`tilt_or_oval`, said once), every frame is
    fitted again that way."""
    settings = PoseSettings.from_config(dataset.config, oval_start=refits, occluded=declared)
    frames, choices = estimate_poses(dataset, show_progress=show_progress, workers=workers,
                                     timer=timer, rings=rings, drop_rings=not refits,
                                     settings=settings)
    if not refits:
        return frames, choices
    with timer("ring + pose"):
        found = tilt_or_oval(dataset, frames, settings.camera)
    if found is None or not found.oval:
        return frames, choices
    report_frame_messages([(-1, OVAL_RUN_NOTE.format(share=found.share,
                                                     frames=_frame_list(found.frames)))])
    return estimate_poses(dataset, show_progress=show_progress, workers=workers, timer=timer,
                          rings=rings, settings=replace(settings, oval_run=True))


OVAL_RUN_NOTE = ("the LED frames of frames {frames} agree best with {share:.0%} of the tilt "
                 "their rings read in a round pipe: the pipe is taken as oval, and each "
                 "frame's tilt is measured from its LED frames")


def _frame_list(frames: Sequence[int]) -> str:
    return ", ".join(f"{i:05d}" for i in frames)


def _finite(values: np.ndarray) -> dict[int, float]:
    return {i: float(v) for i, v in enumerate(values) if np.isfinite(v)}


def _with_odometer(z_mm: dict[int, float], odometry_mm: Mapping[int, float] | None,
                   scale: float) -> dict[int, float]:
    """``z_mm`` with the frames registration did not place (no pose, no usable LED
    frame) put where the odometer says, relative to the placed frames on either side:
    between two, in proportion to the odometer's readings (a slip between them is
    shared); past the last or before the first, the nearest one plus the reading's
    difference times the odometer's fitted ``scale``."""
    odo = {i: v for i, v in (odometry_mm or {}).items() if math.isfinite(v)}
    anchors = sorted(i for i in z_mm if i in odo)
    if not anchors:
        return z_mm
    out = dict(z_mm)
    for i in sorted(set(odo) - set(z_mm)):
        k = bisect.bisect(anchors, i)
        before, after = anchors[k - 1] if k else None, anchors[k] if k < len(anchors) else None
        if before is not None and after is not None and odo[after] != odo[before]:
            share = (odo[i] - odo[before]) / (odo[after] - odo[before])
            out[i] = z_mm[before] + share * (z_mm[after] - z_mm[before])
        else:
            near = before if before is not None else after
            out[i] = z_mm[near] + scale * (odo[i] - odo[near])
    return out


VIEWER = "viewer.html"


def _write_mosaic(out: Path, result: MosaicResult | None, written: WrittenMosaic | None,
                  dataset: Dataset, settings: MosaicSettings,
                  pool: ThreadPoolExecutor) -> Future[Path] | None:
    """mosaic.png (the overview, written by ``pool``: the future), mosaic.json and
    viewer.html.

    The full-resolution ``mosaic.ome.tif`` and the viewer's Deep Zoom ``tiles/`` were
    written while the mosaic was stitched (pipeline/stitched_output.py). Outputs of an
    earlier run into the same folder that this run does not produce are removed, so
    `pipestitch measure` never reads a stale mosaic.
    """
    if result is None or written is None:
        for name in ("mosaic.png", "mosaic.json", PYRAMID, VIEWER, "defects.csv"):
            (out / name).unlink(missing_ok=True)
        shutil.rmtree(out / TILES, ignore_errors=True)
        return None
    (out / "mosaic.tif").unlink(missing_ok=True)   # the tiled TIFF of earlier versions
    png = pool.submit(write_mosaic_png, out / "mosaic.png", written.overview)
    g = written.grid
    write_viewer(out, out / TILES, title=f"pipestitch mosaic: {dataset.root.name}",
                 z0_mm=g.z0_mm, mm_per_px=g.mm_per_px_axial, deg_per_px=g.deg_per_px)
    write_json(out / "mosaic.json", _mosaic_json(result, written, dataset, settings))
    return png


def _report_data(dataset: Dataset, rows: list[FrameRow], written: WrittenMosaic | None,
                 result: MosaicResult | None, summary: RunSummary) -> ReportData:
    total = sum(summary.stage_seconds.values()) or 1.0
    figures = {
        "frame pairs": str(summary.n_frames),
        "placed in the mosaic": str(summary.n_placed),
        "failed (no pose)": str(summary.n_failed),
        "ambiguous": str(summary.n_ambiguous),
        "mirror choices settled by registration": str(len(result.switched) if result else 0),
        "mosaic scale": (f"{result.grid.mm_per_px_axial:g} mm/px, "
                         f"{result.grid.deg_per_px:.4f} deg/px" if result else "no mosaic"),
        "wall time": f"{summary.seconds:.1f} s ({summary.pairs_per_second:.2f} pairs/s)",
        **{f"time in {k}": f"{100 * v / total:.0f} %"
           for k, v in sorted(summary.stage_seconds.items())},
    }
    grid = written.overview_grid if written else None
    image = written.overview if written else None
    return ReportData(f"pipestitch report: {dataset.root.name}", image,
                      grid.z0_mm if grid else 0.0, grid.mm_per_px_axial if grid else 1.0,
                      grid.deg_per_px if grid else 1.0,
                      dataset.config.pipe.inner_diameter_mm, rows,
                      summary.problems, figures, viewer_href=VIEWER if result else None)
