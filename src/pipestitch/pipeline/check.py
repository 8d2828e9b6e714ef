"""The ``check`` stage: validate a dataset with a progress bar over its frames; and the
checks of output paths every command makes before it starts working."""

from __future__ import annotations

import contextlib
import logging
import math
import os
from collections.abc import Iterator
from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from pipestitch.errors import ConfigError, DatasetError, PipestitchError
from pipestitch.io.dataset import (
    Problem,
    VideoDataset,
    check_dataset,
    check_odometry_and_imu,
    count_frame_files,
    open_dataset,
    pairs_held,
)
from pipestitch.pipeline.progress import console

__all__ = ["check_finite", "check_out_file", "check_out_folder_path", "check_video",
           "run_check"]


def _problem(exc: PipestitchError, root: str | Path) -> Problem:
    return Problem(getattr(exc, "path", None) or Path(root), getattr(exc, "problem", str(exc)))


def check_video(root: str | Path, video: str | Path) -> list[Problem]:
    """Validate a dataset whose frames come from ``video``: probe.toml, odometry.csv,
    imu.csv, the video itself (readable, frames of probe.toml's size, laser and LED
    frames told apart); undecodable and dropped frames, timestamp gaps and the
    odometry's warnings (missing rows, z not monotonic) are warnings."""
    try:
        # their warnings (undecodable frames, pairing) are listed here instead
        with _unlogged("pipestitch.io.dataset"), _unlogged("pipestitch.io.video"):
            dataset = open_dataset(root, video=video)
    except PipestitchError as exc:
        return [_problem(exc, root)]
    try:
        _read_first_frame(dataset)   # a video's frames all have one size: one read checks it
        return ([Problem(Path(video), note, "warning") for note in dataset.notes]
                + check_odometry_and_imu(Path(root), dataset.n_pairs, pairs_held(
                    f"the video {Path(video).name}", dataset.n_pairs)))
    except PipestitchError as exc:
        return [_problem(exc, root)]
    finally:
        dataset.close()


def _read_first_frame(dataset: VideoDataset) -> None:
    """Read the first frame the video has: pair 0 may lack its laser frame, which run
    and pose accept."""
    for i in range(dataset.n_pairs):
        if dataset.pairs.laser[i] >= 0:
            dataset.read_laser(i)
            return
        if dataset.pairs.led[i] >= 0:
            dataset.read_led(i)
            return


@contextlib.contextmanager
def _unlogged(name: str) -> Iterator[None]:
    """Drop the records of logger ``name`` for the block."""
    logger = logging.getLogger(name)
    def drop(record: logging.LogRecord) -> bool:
        return False

    logger.addFilter(drop)
    try:
        yield
    finally:
        logger.removeFilter(drop)


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


def check_workers(value: int, option: str = "--workers") -> None:
    """Refuse fewer than one worker given to ``option`` (exit 2, naming it)."""
    if value < 1:
        raise ConfigError(None, f"{option}: expected at least 1, got {value}")


def check_finite(value: float | None, option: str) -> None:
    """Refuse a NaN or infinite value given to ``option`` (None: not given).

    Raises
    ------
    ConfigError
        Naming the option (exit 2).
    """
    if value is not None and not math.isfinite(value):
        raise ConfigError(None, f"{option}: expected a finite number, got {value}")


def _first_existing(path: Path) -> tuple[Path, list[Path]]:
    """The nearest existing folder or file at or above ``path`` and the missing ones
    below it (nearest first)."""
    missing = []
    while not path.exists() and not path.is_symlink() and path.parent != path:
        missing.append(path)
        path = path.parent
    return path, missing


def _creatable(folder: Path, option: str, given: Path) -> None:
    """Raise (naming ``given``, the path the user gave) unless ``folder`` exists and is
    writable, or can be created. Nothing is left behind: folders created to find out
    are removed."""
    what = "the folder" if folder == given else f"its folder {folder}"
    top, missing = _first_existing(folder)
    if not top.is_dir():
        raise DatasetError(given, f"{option}: {top} is a file, not a folder")
    made: list[Path] = []
    try:
        for path in reversed(missing):
            path.mkdir()
            made.append(path)
        if not os.access(folder, os.W_OK | os.X_OK):
            raise PermissionError(13, "Permission denied")
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise DatasetError(given, f"{option}: cannot create or write {what} ({reason})") from None
    finally:
        for path in reversed(made):
            try:
                path.rmdir()
            except OSError:
                pass


def check_out_folder_path(out: str | Path, option: str = "--out") -> Path:
    """An output folder that exists (and is writable) or can be created.

    Raises
    ------
    DatasetError
        Naming the path and the option (exit 2): an existing file, a path under a file,
        or one that cannot be created or written (a read-only place, /proc).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise DatasetError(out, f"{option}: an existing file, not a folder")
    _creatable(out, option, out)
    return out


def check_out_file(path: str | Path, option: str = "--out") -> Path:
    """An output file path whose folder exists or can be created and which is not a
    folder.

    Raises
    ------
    DatasetError
        Naming the path and the option (exit 2).
    """
    path = Path(path)
    if path.is_dir():
        raise DatasetError(path, f"{option}: a folder, expected a file")
    if path.exists() and not os.access(path, os.W_OK):
        raise DatasetError(path, f"{option}: the file is not writable")
    _creatable(path.parent, option, path)
    return path
