"""``pipestitch calibrate``: camera and laser-plane calibration, calibration file formats.

Registered on the main app by cli.py (``register``), which passes its error handler
so bad input exits 2 with a one-line message naming the file.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from pipestitch.errors import ConfigError

if TYPE_CHECKING:   # the calibration code loads when a calibrate command runs
    from pipestitch.pipeline.calibrating import CameraRun, LaserRun

__all__ = ["register"]

_out = Console(highlight=False, soft_wrap=True)
_QUIET = typer.Option("--quiet", "-q", help="No progress bar.")
# pipeline.calibrating.FORMATS (tests/cli/test_app.py checks they agree), written out so
# that the help does not load the calibration code.
FORMATS = ("ocamcalib", "matlab", "opencv")
_FORMAT_HELP = (f"{', '.join(FORMATS)} (default: from the suffix: .txt OCamCalib "
                "calib_results.txt, .yaml/.yml OpenCV, .mat MATLAB, .json MATLAB or OpenCV "
                "by its keys).")


def camera(
    images: Annotated[list[Path], typer.Argument(help="Checkerboard images (one camera).")],
    board: Annotated[str, typer.Option(help="Inner corners COLSxROWS, e.g. 8x6.")],
    square_mm: Annotated[float, typer.Option("--square-mm", help="Square size in mm.")],
    model: Annotated[str, typer.Option(help="ocam (Scaramuzza, valid past 90°) or "
                                       "opencv_fisheye (cv2.fisheye: boards within ~85°).")
                     ] = "ocam",
    out: Annotated[Path, typer.Option("--out", "-o", help="probe.toml to write: its camera "
                                      "section is replaced if it exists, else a new file with "
                                      "SPEC's placeholders (d = 16 mm, 65 mm pipe).")
                   ] = Path("probe.toml"),
    plot: Annotated[Path | None, typer.Option(help="Residual plot PNG to write.")] = None,
    min_views: Annotated[int, typer.Option(help="Fewest usable views.")] = 3,
    quiet: Annotated[bool, _QUIET] = False,
) -> None:
    """Calibrate the camera from checkerboard images; write the camera section of probe.toml.

    Prints the per-image and overall reprojection RMS; images without the board and
    views rejected for their residuals are listed.

    Example: pipestitch calibrate camera calib/*.png --board 8x6 --square-mm 10 --out probe.toml
    """
    from pipestitch.calibrate import Board, parse_board
    from pipestitch.pipeline.calibrating import run_camera_calibration
    from pipestitch.pipeline.check import check_out_file

    try:
        cols, rows = parse_board(board)
    except ValueError:
        raise ConfigError(None, f"--board: expected COLSxROWS inner corners, at least 2x2 "
                                f"(such as 8x6), got {board!r}") from None
    if not (np.isfinite(square_mm) and square_mm > 0):
        raise ConfigError(None, f"--square-mm: expected a positive size in mm, got {square_mm}")
    if model not in ("ocam", "opencv_fisheye"):
        raise ConfigError(None, f"--model: expected ocam or opencv_fisheye, got {model!r}")
    if min_views < 3:
        raise ConfigError(None, f"--min-views: expected at least 3, got {min_views}")
    spec = Board(cols, rows, square_mm)
    check_out_file(out, "--out")
    if plot is not None:
        check_out_file(plot, "--plot")
    result = run_camera_calibration(images, board=spec, model=model, out=out, plot=plot,
                                    min_views=min_views, show_progress=not quiet)
    _print_camera(result)


def _print_camera(result: CameraRun) -> None:
    cal = result.calibration
    table = Table(title=f"{type(cal.camera).__name__}: reprojection error")
    for name in ("view", "corners", "RMS (px)", "max (px)"):
        table.add_column(name, justify="left" if name == "view" else "right")
    for v in cal.views:
        err = np.linalg.norm(v.residuals, axis=1)
        table.add_row(escape(v.name), str(len(err)), f"{v.rms_px:.3f}", f"{np.max(err):.3f}")
    table.add_row("[bold]overall[/]", str(sum(len(v.pixels) for v in cal.views)),
                  f"[bold]{cal.rms_px:.3f}[/]", "")
    _out.print(table)
    for name in result.no_board:
        _out.print(f"[yellow]no board:[/] {escape(name)}")
    for name, reason in cal.rejected:
        _out.print(f"[yellow]rejected:[/] {escape(name)}: {escape(reason)}")
    verb = "updated \\[camera] of" if result.updated else "wrote"
    _out.print(f"{verb} {escape(str(result.out))} ({len(cal.views)} views, RMS "
               f"{cal.rms_px:.3f} px)")
    if result.plot is not None:
        _out.print(f"residual plot: {escape(str(result.plot))}")


def laser(
    frames: Annotated[list[Path], typer.Argument(help="Laser frames in a straight pipe at "
                                                 "several poses (vary tilt and offset).")],
    probe: Annotated[Path, typer.Option(help="probe.toml with the calibrated camera.")],
    pipe_diameter_mm: Annotated[float, typer.Option("--pipe-diameter-mm",
                                                    help="Inner diameter of the pipe, mm.")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="probe.toml to write "
                                             "(default: update --probe in place).")] = None,
    quiet: Annotated[bool, _QUIET] = False,
) -> None:
    """Calibrate the laser plane (distance and normal); write the laser section of probe.toml.

    Example: pipestitch calibrate laser frames/laser_*.png --probe probe.toml --pipe-diameter-mm 65
    """
    from pipestitch.pipeline.calibrating import run_laser_calibration
    from pipestitch.pipeline.check import check_out_file

    if not (np.isfinite(pipe_diameter_mm) and pipe_diameter_mm > 0):
        raise ConfigError(None, f"--pipe-diameter-mm: expected a positive diameter in mm, got "
                                f"{pipe_diameter_mm}")
    check_out_file(probe if out is None else out, "--probe" if out is None else "--out")
    result = run_laser_calibration(frames, probe=probe, pipe_diameter_mm=pipe_diameter_mm,
                                   out=out, show_progress=not quiet)
    _print_laser(result)


def _print_laser(result: LaserRun) -> None:
    fit = result.fit
    n = fit.normal
    _out.print(f"laser plane from {len(result.frames)} frames, {fit.n_points} ring points, "
               f"RMS {fit.rms_mm * 1000:.1f} µm")
    _out.print(f"  distance d = {fit.distance_mm:.4f} mm (± {fit.distance_std_mm:.4f})")
    _out.print(f"  normal n = [{n[0]:.6f}, {n[1]:.6f}, {n[2]:.6f}], tilt {fit.tilt_deg:.3f}° "
               f"(± {fit.normal_std_deg[0]:.3f}°, {fit.normal_std_deg[1]:.3f}°)")
    for name, reason in result.skipped:
        _out.print(f"[yellow]skipped:[/] {escape(name)}: {escape(reason)}")
    _out.print(f"updated \\[laser] of {escape(str(result.out))}")


def import_(
    source: Annotated[Path, typer.Argument(help="Calibration file to read.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="probe.toml to write (its camera "
                                      "section replaced if it exists).")] = Path("probe.toml"),
    fmt: Annotated[str | None, typer.Option("--format", "-f", help=_FORMAT_HELP)] = None,
) -> None:
    """Import an OCamCalib, MATLAB (fisheyeIntrinsics) or OpenCV fisheye calibration.

    Example: pipestitch calibrate import calib_results.txt --out probe.toml
    """
    from pipestitch.pipeline.calibrating import import_calibration
    from pipestitch.pipeline.check import check_out_file

    check_out_file(out, "--out")
    cam, fmt, updated = import_calibration(source, out=out, fmt=fmt)
    verb = "updated \\[camera] of" if updated else "wrote"
    _out.print(f"read {fmt} {escape(str(source))} ({type(cam).__name__} "
               f"{cam.width}x{cam.height}); {verb} {escape(str(out))}")


def export(
    probe: Annotated[Path, typer.Argument(help="probe.toml to read the camera from.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Calibration file to write.")],
    fmt: Annotated[str | None, typer.Option("--format", "-f", help=_FORMAT_HELP)] = None,
) -> None:
    """Export the camera of probe.toml as an OCamCalib, MATLAB or OpenCV calibration file.

    Example: pipestitch calibrate export probe.toml --out intrinsics.json --format matlab
    """
    from pipestitch.pipeline.calibrating import export_calibration
    from pipestitch.pipeline.check import check_out_file

    check_out_file(out, "--out")
    fmt = export_calibration(probe, out, fmt=fmt)
    _out.print(f"wrote {fmt} {escape(str(out))}")


def register(app: typer.Typer, handle_errors: Callable) -> None:
    """Add the ``calibrate`` sub-app (camera, laser, import, export) to ``app``."""
    calibrate_app = typer.Typer(name="calibrate", no_args_is_help=True,
                                help="Calibrate the camera and the laser plane; import and "
                                     "export calibration files.")
    calibrate_app.command(name="camera")(handle_errors(camera))
    calibrate_app.command(name="laser")(handle_errors(laser))
    calibrate_app.command(name="import")(handle_errors(import_))
    calibrate_app.command(name="export")(handle_errors(export))
    app.add_typer(calibrate_app, name="calibrate")
