"""The ``check`` stage: validate a dataset with a progress bar over its frames."""

from __future__ import annotations

from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from pipestitch.io.dataset import Problem, check_dataset, count_frame_files
from pipestitch.pipeline.progress import console

__all__ = ["run_check"]


def run_check(root: str | Path, *, show_progress: bool = True) -> list[Problem]:
    """Validate ``root`` and return every problem (see :func:`check_dataset`)."""
    if not show_progress:
        return check_dataset(root)
    columns = (TextColumn("[bold]checking frames"), BarColumn(), MofNCompleteColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("check", total=count_frame_files(root))
        return check_dataset(root, progress=lambda: progress.advance(task))
