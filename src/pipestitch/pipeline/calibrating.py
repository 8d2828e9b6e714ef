"""Calibration stages: images -> camera model -> probe.toml, laser frames -> [laser], file formats.

Wires :mod:`pipestitch.calibrate` to files: reads the images (with progress),
turns every problem into a :class:`CalibrationError` naming the file, writes
probe.toml atomically (updating only the section calibrated when the file
exists), draws the residual plot, and converts between probe.toml and the
calibration files of OCamCalib, MATLAB and OpenCV.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipestitch.calibrate import (
    Board,
    BoardView,
    CameraCalibration,
    LaserPlaneFit,
    calibrate_camera,
    calibrate_laser_plane,
    detect_board,
)
from pipestitch.camera import CameraModel, OcamModel, OpenCVFisheyeModel
from pipestitch.config import CameraConfig, LaserConfig, ProbeConfig
from pipestitch.errors import CalibrationError, ConfigError, DatasetError
from pipestitch.geometry import Pose
from pipestitch.io.atomic import atomic_path
from pipestitch.io.images import read_image
from pipestitch.io.matlab import read_matlab_fisheye, write_matlab_fisheye
from pipestitch.io.ocamcalib import read_calib_results, write_calib_results
from pipestitch.io.opencv_calib import read_opencv_fisheye, write_opencv_fisheye
from pipestitch.io.probe_toml import (
    probe_config_for,
    read_probe_toml,
    write_probe_toml,
)
from pipestitch.pipeline.progress import track
from pipestitch.pose.fit import fit_pose
from pipestitch.pose.ring import detect_ring
from pipestitch.report.html import agg_pyplot

__all__ = [
    "FORMATS",
    "CameraRun",
    "LaserRun",
    "export_calibration",
    "import_calibration",
    "residual_plot",
    "run_camera_calibration",
    "run_laser_calibration",
]

FORMATS = ("ocamcalib", "matlab", "opencv")
# Placeholders written with a new probe.toml from a camera calibration alone (SPEC's
# reference design); `calibrate laser` and the user replace them.
DEFAULT_PLANE_DISTANCE_MM = 16.0
DEFAULT_PIPE_DIAMETER_MM = 65.0


@dataclass(frozen=True)
class CameraRun:
    """What ``calibrate camera`` did: the fit, the images without a board, the outputs."""

    calibration: CameraCalibration
    no_board: list[str]
    out: Path
    updated: bool
    plot: Path | None = None


@dataclass(frozen=True)
class LaserRun:
    """What ``calibrate laser`` did: the plane fit, skipped frames and the output."""

    fit: LaserPlaneFit
    frames: list[str]
    skipped: list[tuple[str, str]] = field(default_factory=list)
    out: Path = Path("probe.toml")


def _read(path: Path) -> np.ndarray:
    try:
        return read_image(path)
    except DatasetError as exc:
        raise CalibrationError(f"{path}: {exc.problem}") from exc


def _detect_views(paths: Sequence[Path], board: Board, show_progress: bool
                  ) -> tuple[list[BoardView], list[str], tuple[int, int]]:
    views, no_board, size = [], [], None
    for path in track(paths, "detecting boards", total=len(paths), enabled=show_progress):
        try:
            img = _read(path)
        except CalibrationError as exc:   # one bad image is reported and skipped
            no_board.append(f"{path.name} ({exc})")
            continue
        shape = (img.shape[1], img.shape[0])
        if size is None:
            size = shape
        elif shape != size:
            raise CalibrationError(f"{path}: image is {shape[0]}x{shape[1]}, the first image is "
                                   f"{size[0]}x{size[1]} (one camera, one size)")
        view = detect_board(img, board, name=path.name)
        if view is None:
            no_board.append(path.name)
        else:
            views.append(view)
    return views, no_board, size or (0, 0)


def run_camera_calibration(images: Sequence[str | Path], *, board: Board, model: str,
                           out: str | Path, plot: str | Path | None = None,
                           min_views: int = 3, show_progress: bool = True) -> CameraRun:
    """Detect the board in every image, fit ``model``, write probe.toml (and the plot).

    An existing ``out`` keeps its other sections ([laser], [probe], [pipe]); a new
    one gets SPEC's reference placeholders (d = 16 mm, 65 mm pipe).

    Raises
    ------
    CalibrationError
        No images, an unreadable image or one of another size (naming the file), no
        board found in any image, or fewer than ``min_views`` usable views.
    """
    paths = [Path(p) for p in images]
    if not paths:
        raise CalibrationError("no images given")
    views, no_board, (width, height) = _detect_views(paths, board, show_progress)
    if not views:
        raise CalibrationError(f"no {board.cols}x{board.rows} board found in any of the "
                               f"{len(paths)} image(s) (first: {paths[0]}); check --board "
                               "(inner corners, COLSxROWS)")
    if len(views) < min_views:
        raise CalibrationError(f"board found in {len(views)} image(s), at least {min_views} "
                               f"needed (no board in: {', '.join(no_board)})")
    try:
        calibration = calibrate_camera(views, model=model, width=width, height=height,
                                       min_views=min_views)
    except ValueError as exc:
        raise CalibrationError(f"{model} fit failed: {exc}") from exc
    out = Path(out)
    updated = _write_camera(out, calibration.camera)
    plot_path = residual_plot(calibration, plot) if plot is not None else None
    return CameraRun(calibration, no_board, out, updated, plot_path)


def _write_camera(out: Path, camera: CameraModel) -> bool:
    """Write [camera] into ``out``: update an existing probe.toml or start a new one."""
    if out.exists():
        cfg = read_probe_toml(out)
        write_probe_toml(out, cfg.model_copy(update={"camera": CameraConfig.from_model(camera)}))
        return True
    write_probe_toml(out, probe_config_for(camera, plane_distance_mm=DEFAULT_PLANE_DISTANCE_MM,
                                           pipe_diameter_mm=DEFAULT_PIPE_DIAMETER_MM))
    return False


def residual_plot(calibration: CameraCalibration, path: str | Path) -> Path:
    """Residual plot in the report's style: vectors over the image, per-view RMS."""
    plt = agg_pyplot()
    cam = calibration.camera
    fig, (ax_img, ax_bar) = plt.subplots(1, 2, figsize=(12, 4.2),
                                         gridspec_kw={"width_ratios": [1.5, 1]})
    res = np.concatenate([v.residuals for v in calibration.views])
    pix = np.concatenate([v.pixels for v in calibration.views])
    scale = 0.08 * max(cam.width, cam.height) / max(float(np.nanpercentile(
        np.linalg.norm(res, axis=1), 95)), 1e-9)
    palette = plt.cm.tab10 if len(calibration.views) <= 10 else plt.cm.tab20
    colours = palette(np.arange(len(calibration.views)) % palette.N)
    for view, colour in zip(calibration.views, colours, strict=True):
        ax_img.quiver(view.pixels[:, 0], view.pixels[:, 1], view.residuals[:, 0],
                      view.residuals[:, 1], color=colour, angles="xy", scale_units="xy",
                      scale=1 / scale, width=0.003)
    ax_img.plot(pix[:, 0], pix[:, 1], ".", ms=1.5, color="#444")
    ax_img.set(xlim=(0, cam.width), ylim=(cam.height, 0), aspect="equal",
               xlabel="column (px)", ylabel="row (px)",
               title=f"residuals ×{scale:.0f} (projected − detected)")
    names = [v.name for v in calibration.views]
    ax_bar.barh(np.arange(len(names)), [v.rms_px for v in calibration.views], color=colours)
    ax_bar.axvline(calibration.rms_px, color="k", ls="--", lw=1,
                   label=f"overall {calibration.rms_px:.3f} px")
    ax_bar.set(yticks=np.arange(len(names)), yticklabels=names, xlabel="RMS (px)",
               title="per-view reprojection RMS")
    ax_bar.invert_yaxis()
    ax_bar.legend(loc="lower right")
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _ring(path: Path, cfg: ProbeConfig, camera: CameraModel
          ) -> tuple[np.ndarray | None, Pose | None, str]:
    img = _read(path)
    if (img.shape[1], img.shape[0]) != (camera.width, camera.height):
        raise CalibrationError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, the camera in "
                               f"probe.toml is {camera.width}x{camera.height}")
    detection = detect_ring(img, camera)
    radius = cfg.pipe.inner_diameter_mm / 2
    fit = fit_pose(detection, camera, cfg.laser.plane_distance_mm, nominal_radius_mm=radius,
                   fit_radius=False)
    if not fit.ok:
        return None, None, fit.reason
    # the fit's inliers (glints and second candidates removed), not every candidate
    inliers = fit.ring.pixels if fit.ring is not None else detection.best()
    return camera.unproject(np.asarray(inliers, np.float64)), fit.hypotheses[0].pose, ""


def run_laser_calibration(frames: Sequence[str | Path], *, probe: str | Path,
                          pipe_diameter_mm: float, out: str | Path | None = None,
                          min_frames: int = 3, show_progress: bool = True) -> LaserRun:
    """Fit the laser plane to laser frames in a straight pipe; write [laser] of probe.toml.

    Parameters
    ----------
    frames : sequence of path
        Laser frames at several poses (tilt and offset varied).
    probe : path
        probe.toml with the calibrated camera (its [laser] gives the start).
    pipe_diameter_mm : float
        Inner diameter of the calibration pipe.
    out : path, optional
        probe.toml to write (default: ``probe``, updated in place, atomically).
    min_frames : int
        Fewest frames with a ring.

    Raises
    ------
    CalibrationError
        Unreadable frame or wrong size (naming it), too few frames with a ring, or a
        fit that fails.
    """
    probe = Path(probe)
    if not (np.isfinite(pipe_diameter_mm) and pipe_diameter_mm > 0):
        raise CalibrationError(f"--pipe-diameter-mm: expected a positive number, got "
                               f"{pipe_diameter_mm}")
    cfg = read_probe_toml(probe)
    cfg = cfg.model_copy(update={"pipe": cfg.pipe.model_copy(
        update={"inner_diameter_mm": float(pipe_diameter_mm)})})
    camera = cfg.camera_model()
    rays, starts, used, skipped = [], [], [], []
    paths = [Path(p) for p in frames]
    for path in track(paths, "laser rings", total=len(paths), enabled=show_progress):
        try:
            ray, pose, reason = _ring(path, cfg, camera)
        except CalibrationError as exc:   # one bad frame is reported and skipped
            ray, pose, reason = None, None, str(exc)
        if ray is None:
            skipped.append((path.name, reason))
            continue
        rays.append(ray)
        starts.append(pose)
        used.append(path.name)
    if len(rays) < min_frames:
        raise CalibrationError(f"{len(rays)} laser frame(s) with a ring, at least {min_frames} "
                               f"needed (skipped: {', '.join(n for n, _ in skipped) or 'none'})")
    try:
        fit = calibrate_laser_plane(rays, starts, pipe_diameter_mm / 2,
                                    start_distance_mm=cfg.laser.plane_distance_mm)
    except ValueError as exc:
        raise CalibrationError(f"laser plane fit failed: {exc}") from exc
    out = probe if out is None else Path(out)
    laser = LaserConfig(plane_distance_mm=fit.distance_mm, normal=[float(v) for v in fit.normal])
    write_probe_toml(out, read_probe_toml(probe).model_copy(update={"laser": laser}))
    return LaserRun(fit, used, skipped, out)


def _guess_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix == ".txt":
        return "ocamcalib"
    if suffix in (".yaml", ".yml"):
        return "opencv"
    if suffix == ".mat":
        return "matlab"
    if suffix == ".json":
        if path.is_file():
            try:
                keys = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ConfigError(path, f"cannot read as JSON: {exc}") from exc
            if isinstance(keys, dict) and "MappingCoefficients" in keys:
                return "matlab"
            return "opencv"
        raise ConfigError(path, "a .json file is MATLAB or OpenCV: give --format")
    raise ConfigError(path, f"unknown calibration file type {suffix!r}: give --format "
                            f"({', '.join(FORMATS)})")


def import_calibration(source: str | Path, *, out: str | Path, fmt: str | None = None
                       ) -> tuple[CameraModel, str, bool]:
    """Read a calibration file into [camera] of probe.toml ``out`` (updated if it exists).

    Returns the camera, the format read and whether an existing probe.toml was updated.
    """
    source = Path(source)
    fmt = fmt or _guess_format(source)
    readers = {"ocamcalib": read_calib_results, "matlab": read_matlab_fisheye,
               "opencv": read_opencv_fisheye}
    if fmt not in readers:
        raise ConfigError(source, f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    camera = readers[fmt](source)
    return camera, fmt, _write_camera(Path(out), camera)


def export_calibration(probe: str | Path, dest: str | Path, *, fmt: str | None = None) -> str:
    """Write [camera] of probe.toml as an OCamCalib, MATLAB or OpenCV calibration file."""
    probe, dest = Path(probe), Path(dest)
    camera = read_probe_toml(probe).camera_model()
    fmt = fmt or _guess_format_for_writing(dest)
    if fmt in ("ocamcalib", "matlab") and not isinstance(camera, OcamModel):
        raise ConfigError(probe, f"[camera] is {type(camera).__name__}: {fmt} needs the ocam "
                                 "(Scaramuzza) model")
    if fmt == "opencv" and not isinstance(camera, OpenCVFisheyeModel):
        raise ConfigError(probe, "[camera] is the ocam model: opencv needs opencv_fisheye")
    if fmt == "ocamcalib":
        write_calib_results(dest, camera)
    elif fmt == "matlab":
        write_matlab_fisheye(dest, camera)
    elif fmt == "opencv":
        write_opencv_fisheye(dest, camera)
    else:
        raise ConfigError(dest, f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    return fmt


def _guess_format_for_writing(dest: Path) -> str:
    suffix = dest.suffix.lower()
    by_suffix = {".txt": "ocamcalib", ".yaml": "opencv", ".yml": "opencv", ".mat": "matlab"}
    if suffix in by_suffix:
        return by_suffix[suffix]
    raise ConfigError(dest, f"cannot tell the format from {suffix!r}: give --format "
                            f"({', '.join(FORMATS)})")
