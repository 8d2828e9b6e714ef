"""The ``check`` stage: validate a dataset with a progress bar over its frames."""

from __future__ import annotations

from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from pipestitch.errors import PipestitchError
from pipestitch.io.dataset import Problem, check_dataset, count_frame_files, open_dataset
from pipestitch.io.imu import read_imu
from pipestitch.pipeline.progress import console

__all__ = ["check_video", "run_check"]


def _problem(exc: PipestitchError, root: str | Path) -> Problem:
    return Problem(getattr(exc, "path", None) or Path(root), getattr(exc, "problem", str(exc)))


def check_video(root: str | Path, video: str | Path) -> list[Problem]:
    """Validate a dataset whose frames come from ``video``: probe.toml, odometry.csv,
    imu.csv, the video itself (readable, frames of probe.toml's size, laser and LED
    frames told apart); dropped frames and timestamp gaps are warnings."""
    try:
        dataset = open_dataset(root, video=video)
    except PipestitchError as exc:
        return [_problem(exc, root)]
    try:
        dataset.read_laser(0)   # a video's frames all have one size: one read checks it
        read_imu(root)
        return [Problem(Path(video), note, "warning") for note in dataset.notes]
    except PipestitchError as exc:
        return [_problem(exc, root)]
    finally:
        dataset.close()


def run_check(root: str | Path, *, show_progress: bool = True,
              video: str | Path | None = None) -> list[Problem]:
    """Validate ``root`` and return every problem (see :func:`check_dataset`)."""
    if video is not None:
        return check_video(root, video)
    if not show_progress:
        return check_dataset(root)
    columns = (TextColumn("[bold]checking frames"), BarColumn(), MofNCompleteColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("check", total=count_frame_files(root))
        return check_dataset(root, progress=lambda: progress.advance(task))
