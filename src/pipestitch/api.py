"""The Python API: the command line's main jobs as functions returning typed results.

For a notebook or a script::

    import pipestitch.api as ps

    data = ps.simulate("run_data", scenario="default", pairs=6, size="half")
    problems = ps.check(data.path)
    poses = ps.pose(data.path, "run_out")
    result = ps.run(data.path, "run_out")
    print(result.n_placed, "frames in", result.mosaic_png)

Each function does what the command of the same name does (``pipestitch simulate``,
``check``, ``pose``, ``run``, ``measure``, ``export``), writes the same files, and
raises :class:`pipestitch.errors.PipestitchError` subclasses for bad input, as the
command exits 2 for them. Progress bars are off unless asked for. See docs/api.md.

May import ``pipeline``, ``io``, ``measure`` (result types), ``simulate``, ``config``,
``errors``; nothing imports it but ``cli``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io.dataset import Problem
from pipestitch.measure.defects import Defect
from pipestitch.pipeline.check import run_check
from pipestitch.pipeline.coding import EXPORTS, export_run
from pipestitch.pipeline.measuring import measure_run
from pipestitch.pipeline.posing import run_pose
from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.simulating import simulate_dataset
from pipestitch.simulate.scenarios import SCENARIOS

__all__ = ["EXPORTS", "SCENARIOS", "MeasureResult", "PoseResult", "RunResult",
           "SimulatedDataset", "check", "export", "measure", "pose", "read_table", "run",
           "simulate"]


@dataclass(frozen=True)
class SimulatedDataset:
    """A dataset folder written by :func:`simulate`.

    Attributes
    ----------
    path : Path
        The dataset folder (probe.toml, frames/, truth/).
    n_pairs : int
        Number of frame pairs.
    scenario : str
        The scenario's name.
    """

    path: Path
    n_pairs: int
    scenario: str


@dataclass(frozen=True)
class PoseResult:
    """What :func:`pose` found.

    Attributes
    ----------
    poses_csv : Path
        ``OUT/poses.csv`` (SPEC's columns, then the extra ones).
    n_frames, n_failed, n_ambiguous : int
        Frames in the dataset, frames without a pose, frames whose mirror ambiguity was
        not resolved.
    table : dict of str to ndarray
        poses.csv as columns: numbers as float arrays (``nan`` where empty), the
        ``error``, ``chosen_by``, ``model`` and ``warning`` columns as string arrays.
    """

    poses_csv: Path
    n_frames: int
    n_failed: int
    n_ambiguous: int
    table: dict[str, np.ndarray] = field(repr=False)


@dataclass(frozen=True)
class RunResult:
    """What :func:`run` made.

    Attributes
    ----------
    out : Path
        The output folder.
    n_frames, n_failed, n_ambiguous, n_placed : int
        Frames in the dataset, without a pose, with an unresolved mirror ambiguity, and
        placed in the mosaic.
    seconds : float
        Wall time of the run.
    problems : list of (int, str)
        Frames reported and skipped, with the reason (frame -1: the run as a whole).
    no_mosaic : str
        Why there is no mosaic ("" when there is one).
    failed : bool
        The run failed (no frame has a pose, or the LED frames gave no mosaic): ``out``
        is then the folder its outputs were kept in; the previous run's outputs in the
        requested folder are left as they were.
    """

    out: Path
    n_frames: int
    n_failed: int
    n_ambiguous: int
    n_placed: int
    seconds: float
    problems: list[tuple[int, str]]
    no_mosaic: str
    failed: bool = False

    @property
    def mosaic_png(self) -> Path | None:
        """``OUT/mosaic.png``, or None when the run made no mosaic."""
        path = self.out / "mosaic.png"
        return path if path.is_file() else None

    @property
    def poses(self) -> dict[str, np.ndarray]:
        """``OUT/poses.csv`` as columns (see :func:`read_table`)."""
        return read_table(self.out / "poses.csv")

    @property
    def defects(self) -> dict[str, np.ndarray]:
        """``OUT/defects.csv`` as columns (empty when the run made no mosaic)."""
        path = self.out / "defects.csv"
        return read_table(path) if path.is_file() else {}


@dataclass(frozen=True)
class MeasureResult:
    """What :func:`measure` found: the defects and the file they were written to."""

    defects_csv: Path
    defects: list[Defect]


def read_table(path: str | Path) -> dict[str, np.ndarray]:
    """A CSV output of pipestitch (poses.csv, defects.csv, profile.csv) as columns.

    Columns whose every non-empty cell is a number become float arrays (``nan`` for
    empty or ``nan`` cells); the others stay string arrays.

    Raises
    ------
    DatasetError
        When the file cannot be read.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            header, *rows = list(csv.reader(handle))
    except (OSError, ValueError, csv.Error, UnicodeDecodeError) as exc:
        raise DatasetError(path, f"cannot read the table ({exc})") from exc
    columns = zip(*[(row + [""] * len(header))[:len(header)] for row in rows], strict=True)
    return {name: _column(list(cells)) for name, cells in
            zip(header, columns if rows else [[] for _ in header], strict=True)}


def _column(cells: list[str]) -> np.ndarray:
    try:
        return np.array([float(c) if c.strip() else math.nan for c in cells], float)
    except ValueError:
        return np.array(cells, dtype=str)


def simulate(out: str | Path, *, scenario: str = "default", pairs: int | None = None,
             size: str = "half", seed: int = 0, progress: bool = False,
             led_share: float = 0.0) -> SimulatedDataset:
    """Simulate a probe run and write it as a dataset folder (``pipestitch simulate``).

    Parameters
    ----------
    out : path
        The dataset folder to write.
    scenario : str, keyword-only
        One of :data:`SCENARIOS` (``default``, ``test_piece``, ``corrosion``, ...).
    pairs : int, optional
        Number of frame pairs (default: the scenario's).
    size : {"half", "full"}
        Frame size: 1224 x 1024 or the reference design's 2448 x 2048.
    seed : int
        Seed of the wall texture, trajectory and noise.
    progress : bool
        Show a progress bar.
    led_share : float
        The share of the step to the next pair by which each LED frame follows its laser
        frame, the probe moving on between the two (``--led-share``; 0: taken together).

    Raises
    ------
    ValueError
        For an unknown scenario or size, or a share out of (-1, 1).
    """
    if scenario not in SCENARIOS:
        raise ValueError(f"scenario: expected one of {', '.join(SCENARIOS)}, got {scenario!r}")
    synthetic = simulate_dataset(replace(SCENARIOS[scenario], led_share=led_share), out,
                                 seed=seed, size=size, n_pairs=pairs, show_progress=progress)
    return SimulatedDataset(Path(out), len(synthetic.poses), scenario)


def check(dataset: str | Path, *, video: str | Path | None = None) -> list[Problem]:
    """Every problem of a dataset folder (``pipestitch check``): errors and warnings.

    An empty list means the dataset is valid.
    """
    return run_check(dataset, show_progress=False, video=video)


def pose(dataset: str | Path, out: str | Path, *, workers: int = 2,
         video: str | Path | None = None, progress: bool = False) -> PoseResult:
    """Estimate the pose of every frame and write ``OUT/poses.csv`` (``pipestitch pose``)."""
    Path(out).mkdir(parents=True, exist_ok=True)
    summary = run_pose(dataset, out, show_progress=progress, workers=workers,
                       video=None if video is None else Path(video))
    return PoseResult(summary.path, summary.n_frames, summary.n_failed, summary.n_ambiguous,
                      read_table(summary.path))


def run(dataset: str | Path, out: str | Path, *, video: str | Path | None = None,
        crown_deg: float | None = None, tolerance_pct: float = 1.0,
        progress: bool = False) -> RunResult:
    """Process a dataset end to end and write every output into ``out`` (``pipestitch run``).

    Parameters
    ----------
    dataset : path
        The dataset folder (SPEC's layout).
    out : path
        The output folder: poses.csv, mosaic.png/.json, defects.csv, profile.csv,
        report.html and the rest (see the README).
    video : path, optional
        A video of alternating laser/LED frames instead of frames/.
    crown_deg : float, optional
        Mosaic theta of 12 o'clock (default: imu.csv, else a detected invert, else
        relative).
    tolerance_pct : float
        profile.csv flags diameters further than this from nominal.
    progress : bool
        Show progress bars.
    """
    summary = run_dataset(dataset, out, show_progress=progress, tolerance_pct=tolerance_pct,
                          video=None if video is None else Path(video), crown_deg=crown_deg)
    return RunResult(Path(summary.out), summary.n_frames, summary.n_failed,
                     summary.n_ambiguous, summary.n_placed, summary.seconds,
                     list(summary.problems), summary.no_mosaic, summary.mosaic_failed)


def measure(out: str | Path, *, crown_deg: float | None = None) -> MeasureResult:
    """Measure the defects of a finished run's mosaic again (``pipestitch measure``)."""
    path, defects = measure_run(out, crown_deg=crown_deg)
    return MeasureResult(path, defects)


def export(out: str | Path, fmt: str, *, dest: str | Path | None = None,
           crown_deg: float | None = None) -> Path:
    """Write a run's coded observations in one exchange format (``pipestitch export``).

    ``fmt`` is one of :data:`EXPORTS` (``en13508``, ``pacp-csv``, ``json``, ...).
    """
    return export_run(out, fmt, dest=dest, crown_deg=crown_deg)
