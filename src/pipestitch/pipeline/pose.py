"""The ``pose`` stage: every laser frame -> ring -> both hypotheses -> run-level choice.

Frames are processed in order on a small thread pool (OpenCV and most numpy work
release the GIL). A frame that cannot be read or has no usable ring is reported and
kept as a row with its error, never dropped. Output: ``poses.csv`` per SPEC, with
extra columns after SPEC's (error, how the hypothesis was chosen, uncertainties).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipestitch.ambiguity import Choice, envelope_costs, resolve_run
from pipestitch.errors import DatasetError
from pipestitch.geometry import BodyEnvelope
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.dataset import Dataset, open_dataset
from pipestitch.pipeline.progress import console, track
from pipestitch.pose_fit import PoseFit, fit_pose
from pipestitch.ring import detect_ring

__all__ = ["POSE_COLUMNS", "FramePose", "estimate_poses", "run_pose", "write_poses_csv"]

POSE_COLUMNS = ("frame", "alpha_deg", "beta_deg", "dx_mm", "dy_mm", "z_mm", "roll_deg",
                "radius_mm", "ovality", "rms_px", "ambiguous", "alt_alpha_deg", "alt_beta_deg",
                "alt_dx_mm", "alt_dy_mm")
EXTRA_COLUMNS = ("error", "chosen_by", "margin", "n_points", "coverage", "model",
                 "alpha_std_deg", "beta_std_deg", "dx_std_mm", "dy_std_mm", "radius_std_mm")


@dataclass(frozen=True)
class FramePose:
    """Pose result of one frame: a fit, or the error that prevented it."""

    index: int
    fit: PoseFit
    error: str = ""


def _one_frame(dataset: Dataset, index: int) -> FramePose:
    cfg = dataset.config
    try:
        img = dataset.read_laser(index)
    except DatasetError as exc:
        return FramePose(index, PoseFit(False, exc.problem), f"{exc.path.name}: {exc.problem}")
    camera = cfg.camera_model()
    led = None
    if dataset.has_led:
        try:
            led = dataset.read_led(index)
        except DatasetError:
            led = None  # the laser frame alone still gives a pose, a little less exact
    detection = detect_ring(img, camera, reflectance=led)
    fit = fit_pose(detection, camera, cfg.laser.plane_distance_mm,
                   nominal_radius_mm=cfg.pipe.inner_diameter_mm / 2)
    return FramePose(index, fit, "" if fit.ok else fit.reason)


def _ordered(dataset: Dataset, workers: int) -> Iterator[FramePose]:
    if workers <= 1:
        for i in range(dataset.n_pairs):
            yield _one_frame(dataset, i)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        yield from pool.map(lambda i: _one_frame(dataset, i), range(dataset.n_pairs))


def estimate_poses(dataset: Dataset, *, show_progress: bool = True,
                   workers: int = 2) -> tuple[list[FramePose], list[Choice]]:
    """Fit every frame and choose between the mirror hypotheses over the run."""
    frames = list(track(_ordered(dataset, workers), "pose", total=dataset.n_pairs,
                        enabled=show_progress))
    body = BodyEnvelope(dataset.config.probe.length_mm, dataset.config.probe.diameter_mm)
    unary = np.array([envelope_costs(f.fit, body) if f.fit.ok else np.zeros(2) for f in frames])
    choices = resolve_run([f.fit for f in frames], unary)
    return frames, choices


def _fmt(value: float, digits: int = 6) -> str:
    return "nan" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _row(frame: FramePose, choice: Choice, z_mm: float | None) -> list[str]:
    fit = frame.fit
    if not fit.ok or choice.chosen is None:
        nan = ["nan"] * 9
        return [str(frame.index), *nan, "1", *["nan"] * 4, frame.error or fit.reason,
                "none", "nan", str(fit.n_points), _fmt(fit.coverage, 3), fit.model,
                *["nan"] * 5]
    h = fit.hypotheses[choice.chosen]
    alt = fit.hypotheses[1 - choice.chosen]
    d, a = h.pose.as_degrees(), alt.pose.as_degrees()
    std = h.std
    return [str(frame.index), _fmt(d["alpha_deg"]), _fmt(d["beta_deg"]), _fmt(d["dx_mm"]),
            _fmt(d["dy_mm"]), _fmt(z_mm if z_mm is not None else math.nan), "nan",
            _fmt(h.radius_mm), "nan", _fmt(h.rms_px, 4), "1" if choice.ambiguous else "0",
            _fmt(a["alpha_deg"]), _fmt(a["beta_deg"]), _fmt(a["dx_mm"]), _fmt(a["dy_mm"]),
            "", choice.reason, _fmt(choice.margin, 2), str(fit.n_points), _fmt(fit.coverage, 3),
            fit.model, _fmt(math.degrees(std.get("alpha", math.nan))),
            _fmt(math.degrees(std.get("beta", math.nan))), _fmt(std.get("dx_mm", math.nan)),
            _fmt(std.get("dy_mm", math.nan)), _fmt(std.get("radius_mm", math.nan))]


def write_poses_csv(path: Path, frames: list[FramePose], choices: list[Choice],
                    odometry_mm: dict[int, float] | None) -> Path:
    """Write poses.csv (SPEC columns first, then the extra ones), atomically.

    ``z_mm`` comes from the odometer when the dataset has one (registration refines
    it later); ``roll_deg`` and ``ovality`` are not measured by the ring alone and
    are written as nan until the stages that measure them run.
    """
    lines = [",".join(POSE_COLUMNS + EXTRA_COLUMNS)]
    for frame, choice in zip(frames, choices, strict=True):
        z = odometry_mm.get(frame.index) if odometry_mm else None
        lines.append(",".join(_row(frame, choice, z)))
    return atomic_write_text(path, "\n".join(lines) + "\n")


@dataclass(frozen=True)
class PoseSummary:
    """Counts reported by the CLI."""

    n_frames: int
    n_failed: int
    n_ambiguous: int
    path: Path


def run_pose(root: str | Path, out: str | Path, *, show_progress: bool = True,
             workers: int = 2) -> PoseSummary:
    """Estimate the pose of every frame of a dataset and write ``OUT/poses.csv``."""
    dataset = open_dataset(root)
    frames, choices = estimate_poses(dataset, show_progress=show_progress, workers=workers)
    for f in frames:
        if f.error:
            console.print(f"[yellow]frame {f.index:05d}[/]: {f.error}", highlight=False)
    path = write_poses_csv(Path(out) / "poses.csv", frames, choices, dataset.odometry_mm)
    return PoseSummary(len(frames), sum(1 for f in frames if not f.fit.ok),
                       sum(1 for c in choices if c.ambiguous), path)
