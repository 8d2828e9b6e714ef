"""Command-line interface: parse arguments, call the pipeline, map errors to exit codes.

Exit codes (SPEC): 0 success, 2 bad input (the message names the file and the
problem), 1 processing failure. No traceback reaches the user for expected errors.
"""

from __future__ import annotations

import errno
import functools
import os
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn, TypeVar

import click
import typer
from rich.markup import escape

from pipestitch import __version__
from pipestitch.cli import interrupted
from pipestitch.cli.batch_command import batch
from pipestitch.cli.calibrate_command import register as register_calibrate
from pipestitch.cli.export_command import CROWN_HELP
from pipestitch.cli.export_command import register as register_export
from pipestitch.cli.mask_command import register as register_mask
from pipestitch.cli.review_command import register as register_review
from pipestitch.errors import PipestitchError
from pipestitch.pipeline.progress import console
from pipestitch.simulate.scenarios import SCENARIOS, led_share_problem

if TYPE_CHECKING:
    from pipestitch.pipeline.run import RunSummary

# The pipeline is imported by the command that runs it, inside its body: `--help`, a
# usage error or a light command (check, export) does not load the mosaic stages,
# scipy or the compiled kernels.

__all__ = ["app", "main"]

app = typer.Typer(
    name="pipestitch",
    help="Small-bore pipe inspection: probe pose from the laser ring, centralised unwrapping, "
         "stitching and measurement.\n\nExample: pipestitch demo --out /tmp/demo",
    no_args_is_help=True,
    add_completion=False,
    rich_markup_mode="rich",
)
F = TypeVar("F", bound=Callable[..., object])
VIDEO_HELP = ("Video of alternating laser/LED frames to read instead of DATASET/frames/ "
              "(probe.toml and odometry.csv still from DATASET).")


# OSErrors about a path the user gave (a missing input, an output where a folder or a
# file is in the way, a read-only place): bad input, exit 2. Others (a full disk) exit 1.
_PATH_ERRNOS = {errno.ENOENT, errno.EEXIST, errno.ENOTDIR, errno.EISDIR, errno.EACCES,
                errno.EPERM, errno.EROFS, errno.ENAMETOOLONG}


def _error(message: str, code: int) -> typer.Exit:
    console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)


def _handle_errors(func: F) -> F:
    """Turn pipestitch errors into a one-line message and the SPEC exit code.

    Also a usage error raised in a command's body (``typer.BadParameter``: exit 2) and an
    OSError naming a path the user gave (exit 2): one line, never a traceback. Ctrl-C
    (exit 130) includes an error a library made of it (see
    :func:`pipestitch.cli.interrupted`).
    """
    @functools.wraps(func)
    def wrapper(*args: object, **kwargs: object) -> object:
        try:
            return func(*args, **kwargs)
        except KeyboardInterrupt:
            raise _interrupted() from None
        except (typer.Exit, typer.Abort):
            raise
        except Exception as exc:
            if interrupted(exc):   # Ctrl-C that a library turned into an error of its own
                raise _interrupted() from None
            raise _mapped(exc) from None
    return wrapper  # type: ignore[return-value]


def _interrupted() -> typer.Exit:
    console.print("[bold red]interrupted[/]")
    return typer.Exit(130)


def _mapped(exc: Exception) -> typer.Exit:
    """The one-line message and exit code of an error a command raised."""
    if isinstance(exc, PipestitchError):
        return _error(str(exc), exc.exit_code)
    if isinstance(exc, (click.ClickException, typer.TyperException)):
        # typer.BadParameter (typer's own click) or click's: usage errors, exit 2
        message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
        return _error(" ".join(message.split()), getattr(exc, "exit_code", 2))
    if isinstance(exc, OSError) and exc.errno in _PATH_ERRNOS and exc.filename:
        return _error(f"{exc.filename}: {exc.strerror}", 2)
    _unexpected(exc)


def _unexpected(exc: Exception) -> NoReturn:
    # A bug or an unexpected failure: exit 1 with one line; the traceback is there for
    # developers with PIPESTITCH_DEBUG=1.
    if os.environ.get("PIPESTITCH_DEBUG"):
        raise exc
    console.print(f"[bold red]processing failed:[/] {escape(repr(exc))} "
                  "(set PIPESTITCH_DEBUG=1 for the traceback)", soft_wrap=True)
    raise typer.Exit(1) from None


def _checked(files: dict[str, str] | None = None,
             finite: dict[str, str] | None = None) -> Callable[[F], F]:
    """An error handler (as ``_handle_errors``) that first checks the command's output
    file options (parameter name -> option) and its options that must be finite: for
    the commands registered from other modules (export, mask)."""
    def handle(func: F) -> F:
        @functools.wraps(func)
        def wrapper(*args: object, **kwargs: object) -> object:
            from pipestitch.pipeline.check import check_finite, check_out_file

            for name, option in (finite or {}).items():
                check_finite(kwargs.get(name), option)  # type: ignore[arg-type]
            for name, option in (files or {}).items():
                if kwargs.get(name) is not None:
                    check_out_file(kwargs[name], option)  # type: ignore[arg-type]
            return func(*args, **kwargs)
        return _handle_errors(wrapper)  # type: ignore[arg-type]
    return handle


def _version(value: bool) -> None:
    if value:
        typer.echo(f"pipestitch {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: Annotated[bool, typer.Option("--version", callback=_version,
                                                is_eager=True, help="Print the version.")] = False
          ) -> None:
    """pipestitch command line."""


def _scenario_help() -> str:
    return "; ".join(f"{name}: {s.description}" for name, s in SCENARIOS.items())


@app.command()
@_handle_errors
def simulate(
    out: Annotated[Path, typer.Option("--out", "-o", help="Dataset folder to write.")],
    scenario: Annotated[str, typer.Option(help="Scenario name. " + _scenario_help())] = "default",
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same dataset).")] = 0,
    size: Annotated[str, typer.Option(help="Sensor size: full (2448x2048) or half (1224x1024).")
                    ] = "full",
    pairs: Annotated[int | None, typer.Option(help="Override the number of frame pairs.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    workers: Annotated[int, typer.Option(help="Processes rendering frames (same output).")] = 1,
    led_share: Annotated[float, typer.Option(
        help="Share of the step to the next pair by which each LED frame follows its laser "
             "frame, the probe moving on between the two (0.5: frames alternating at a "
             "steady rate; negative: the LED frame first; truth/led_poses.csv has their "
             "poses); default 0, taken together.")] = 0.0,
) -> None:
    """Simulate a probe run and write it as a dataset (SPEC layout, with truth/).

    Example: pipestitch simulate --scenario test_piece --size half --out data/test_piece
    """
    from pipestitch.pipeline.check import check_out_folder_path
    from pipestitch.pipeline.simulating import simulate_dataset

    if scenario not in SCENARIOS:
        console.print(f"[bold red]error:[/] unknown scenario {scenario!r}; choose from "
                      f"{', '.join(SCENARIOS)}")
        raise typer.Exit(2)
    if size not in ("full", "half"):
        console.print(f"[bold red]error:[/] --size: expected full or half, got {size!r}")
        raise typer.Exit(2)
    if pairs is not None and pairs < 1:
        console.print(f"[bold red]error:[/] --pairs: expected at least 1, got {pairs}")
        raise typer.Exit(2)
    if workers < 1:
        console.print(f"[bold red]error:[/] --workers: expected at least 1, got {workers}")
        raise typer.Exit(2)
    chosen = replace(SCENARIOS[scenario], led_share=led_share)
    if (problem := led_share_problem(chosen)) is not None:
        console.print(f"[bold red]error:[/] --{problem.replace('_', '-')}")
        raise typer.Exit(2)
    check_out_folder_path(out)
    run = simulate_dataset(chosen, out, seed=seed, size=size, n_pairs=pairs,
                           show_progress=not quiet, workers=workers)
    typer.echo(f"wrote {len(run.poses)} pairs of scenario {scenario!r} to {out}")


def _print_problems(problems: list) -> None:
    # One line per problem, never wrapped: paths stay whole and greppable.
    for p in problems:
        colour = "red" if p.severity == "error" else "yellow"
        line = f"[{colour}]{p.severity}[/]: {escape(str(p.path))}: {escape(p.message)}"
        console.print(line, soft_wrap=True, highlight=False)


@app.command()
@_handle_errors
def check(
    dataset: Annotated[Path, typer.Argument(help="Dataset folder (SPEC layout).")],
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    video: Annotated[Path | None, typer.Option(
        "--video", help="Frames from this video (alternating laser/LED) instead of "
                        "DATASET/frames/.")] = None,
) -> None:
    """Validate a dataset: layout, numbering, image sizes, readable frames, probe.toml, CSVs.

    Lists every problem with its file; exits with 2 if any is an error. With --video,
    the video is read through (dropped frames and timestamp gaps are warnings).

    Example: pipestitch check data/test_piece
    """
    from pipestitch.pipeline.check import run_check

    problems = run_check(dataset, show_progress=not quiet, video=video)
    errors = [p for p in problems if p.severity == "error"]
    if problems:
        _print_problems(problems)
    if errors:
        console.print(f"[bold red]{len(errors)} error(s)[/] in {dataset}")
        raise typer.Exit(2)
    typer.echo(f"{dataset}: OK ({len(problems)} warning(s))")


@app.command()
@_handle_errors
def pose(
    dataset: Annotated[Path, typer.Argument(help="Dataset folder (SPEC layout).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder for poses.csv.")],
    workers: Annotated[int, typer.Option(help="Threads (frames stay in order).")] = 2,
    video: Annotated[Path | None, typer.Option(help=VIDEO_HELP)] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Estimate the probe pose of every frame from its laser ring; write OUT/poses.csv.

    Both mirror hypotheses are kept (alt_* columns); the chosen one is decided by the
    probe envelope and the photometric consistency of consecutive LED frames, and
    carried along the run by temporal continuity; undecided frames are flagged
    ambiguous (chosen_by says why). Frames without a usable ring are reported and kept
    with an error.

    Example: pipestitch pose data/test_piece --out out/test_piece
    """
    from pipestitch.pipeline.warm_start import loading_stages

    with loading_stages():
        from pipestitch.pipeline.check import check_workers
        from pipestitch.pipeline.posing import run_pose
        from pipestitch.pipeline.staging import check_out_folder

    check_out_folder(dataset, out)   # not inside the dataset, a folder that can be written
    check_workers(workers)
    summary = run_pose(dataset, out, show_progress=not quiet, workers=workers,
                       video=video)
    typer.echo(f"wrote {summary.path}: {summary.n_frames} frames, {summary.n_failed} failed, "
               f"{summary.n_ambiguous} ambiguous")
    if summary.n_failed == summary.n_frames:
        console.print("[bold red]error:[/] no frame gave a pose (see the errors above)")
        raise typer.Exit(1)


@app.command()
@_handle_errors
def run(
    dataset: Annotated[Path, typer.Argument(help="Dataset folder (SPEC layout).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    mm_per_px: Annotated[float | None, typer.Option(
        "--mm-per-px", help="Mosaic scale on the wall, mm per pixel on both axes (default: "
        "the camera's axial resolution half a radius ahead).")] = None,
    unwrap: Annotated[str, typer.Option(
        help="ours (centralised, default), centred (pose forced to a centred probe) or "
             "polar (prior-art polar unwrap about the image centre).")] = "ours",
    workers: Annotated[int, typer.Option(help="Threads (frames stay in order).")] = 2,
    tolerance_pct: Annotated[float, typer.Option(
        "--diameter-tolerance-pct", help="profile.csv flags diameters further than this "
        "from the nominal (probe.toml), in %.")] = 1.0,
    video: Annotated[Path | None, typer.Option(help=VIDEO_HELP)] = None,
    crown_deg: Annotated[float | None, typer.Option("--crown-deg", help=CROWN_HELP)] = None,
    fine_registration: Annotated[bool, typer.Option(
        "--fine-registration", help="Two registration rounds, the second on the mosaic's "
        "own scale: the refined tilt to a few thousandths of a degree instead of a few "
        "hundredths (the mosaic looks the same), at ~1.3x the time.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Process a run end to end: pose, centralised unwrap, registration, mosaic, report.

    Writes OUT/poses.csv, mosaic.png, mosaic.json, mosaic.ome.tif + tiles/ + viewer.html
    (zoomable full resolution), defects.csv, profile.csv, observations and report.html.
    Frames that fail are reported and skipped, never dropped silently.
    A dataset without LED frames gets poses, profile and report only. The outputs replace
    an earlier run's in OUT only when the run succeeds, as one set (files you added are
    kept); exit 1 when no frame has a pose or the LED frames give no mosaic, OUT's outputs
    left as they were and this run's kept in OUT/.pipestitch-partial-PID.

    Example: pipestitch run data/test_piece --out out/test_piece
    """
    from pipestitch.pipeline.warm_start import decode_ahead

    with decode_ahead(dataset, video=video):   # while the stages load
        summary = _run(dataset, out, mm_per_px=mm_per_px, unwrap=unwrap, workers=workers,
                       tolerance_pct=tolerance_pct, video=video, crown_deg=crown_deg,
                       fine_registration=fine_registration, quiet=quiet)
    _print_run(summary)
    if summary.mosaic_failed:
        console.print(f"[bold red]error:[/] {escape(summary.no_mosaic)}")
        raise typer.Exit(1)


def _run(dataset: Path, out: Path, *, mm_per_px: float | None, unwrap: str, workers: int,
         tolerance_pct: float, video: Path | None, crown_deg: float | None,
         fine_registration: bool, quiet: bool) -> RunSummary:
    """`run`'s options checked, then the run (the stages are imported here)."""
    from pipestitch.pipeline.warm_start import loading_stages

    with loading_stages():
        from pipestitch.pipeline.check import check_finite, check_workers
        from pipestitch.pipeline.run import run_dataset
        from pipestitch.pipeline.staging import check_out_folder
        from pipestitch.pipeline.stitching import MosaicSettings

    try:
        make = MosaicSettings.fine if fine_registration else MosaicSettings
        check_workers(workers)
        settings = make(mm_per_px=mm_per_px, mode=unwrap, workers=workers)
        if not 0 <= tolerance_pct < 100:
            raise ValueError(f"--diameter-tolerance-pct: expected 0 to 100, got {tolerance_pct}")
    except ValueError as exc:
        console.print(f"[bold red]error:[/] {escape(str(exc))}")
        raise typer.Exit(2) from None
    check_finite(crown_deg, "--crown-deg")
    check_out_folder(dataset, out)
    return run_dataset(dataset, out, settings=settings, show_progress=not quiet,
                       tolerance_pct=tolerance_pct, video=video, crown_deg=crown_deg)


def _print_run(summary: RunSummary) -> None:
    typer.echo(f"{summary.n_frames} pairs: {summary.n_placed} in the mosaic, "
               f"{summary.n_failed} without a pose, {summary.n_ambiguous} ambiguous; "
               f"{summary.seconds:.1f} s ({summary.pairs_per_second:.2f} pairs/s)")
    typer.echo(f"report: {summary.out / 'report.html'}")


@app.command()
@_handle_errors
def measure(
    out: Annotated[Path, typer.Argument(help="Output folder of `pipestitch run` (mosaic.png "
                                             "and mosaic.json).")],
    crown_deg: Annotated[float | None, typer.Option("--crown-deg", help=CROWN_HELP)] = None,
) -> None:
    """Find and measure defects (holes, spots) on an existing run's mosaic: OUT/defects.csv.

    z and theta are in the mosaic's coordinates; clock positions have 12 o'clock at the
    crown by the best reference (--crown-deg, the dataset's imu.csv, a detected invert),
    else at the first frame's image up; clockwise looking along the survey
    (docs/conventions.md). Also re-codes the observations (pipestitch export).

    Example: pipestitch measure out/test_piece
    """
    from pipestitch.pipeline.check import check_finite
    from pipestitch.pipeline.coding import check_observations, code_run
    from pipestitch.pipeline.measuring import measure_run
    from pipestitch.pipeline.staging import out_lock

    check_finite(crown_deg, "--crown-deg")
    check_observations(out)   # refused user rows: before defects.csv is written
    with out_lock(out, "measure"):
        path, defects = measure_run(out, crown_deg=crown_deg)
        coded = code_run(out, crown_deg=crown_deg)  # clocks by the best reference
    typer.echo(f"clock reference: {coded.reference.source}; "
               f"{len(coded.observations)} observations in {out / 'observations.csv'}")
    holes = sum(1 for d in defects if d.kind == "hole")
    typer.echo(f"wrote {path}: {len(defects)} defects ({holes} holes, "
               f"{len(defects) - holes} spots)")


@app.command()
@_handle_errors
def demo(
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Folder for the demo (default: "
                                             "a new temporary folder).")] = None,
    size: Annotated[str, typer.Option(help="Sensor size: full or half.")] = "half",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Simulate a short probe run, check it and process it end to end (mosaic and report).

    Example: pipestitch demo --out /tmp/pipestitch-demo
    """
    from pipestitch.pipeline.warm_start import loading_stages

    with loading_stages():
        from pipestitch.pipeline.check import check_out_folder_path, run_check
        from pipestitch.pipeline.run import run_dataset
        from pipestitch.pipeline.simulating import simulate_dataset, simulated_before

    if size not in ("full", "half"):
        raise _error(f"--size: expected full or half, got {size!r}", 2)
    if out is not None:
        check_out_folder_path(out)
    root = out if out is not None else Path(tempfile.mkdtemp(prefix="pipestitch-demo-"))
    dataset = root / "dataset"
    reused = simulated_before(dataset, "default", 0, size)
    if not reused:
        simulate_dataset(SCENARIOS["default"], dataset, seed=0, size=size,
                         show_progress=not quiet, workers=min(2, os.cpu_count() or 1))
    problems = [p for p in run_check(dataset, show_progress=not quiet) if p.severity == "error"]
    if problems:
        _print_problems(problems)
        raise typer.Exit(1)
    pairs = len(list((dataset / "frames").glob("laser_*")))
    made = "made by an earlier demo, " if reused else ""
    typer.echo(f"demo dataset: {dataset} ({pairs} pairs, {made}checked OK)")
    _print_run(run_dataset(dataset, root / "out", show_progress=not quiet))


app.command(name="batch")(_handle_errors(batch))
register_export(app, _checked(files={"dest": "--out"}, finite={"crown_deg": "--crown-deg"}))
register_calibrate(app, _handle_errors)
register_mask(app, _checked(files={"out": "--out"}))
register_review(app, _handle_errors)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
