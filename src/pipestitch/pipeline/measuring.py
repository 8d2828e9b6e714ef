"""The measurement stage: defects on the mosaic -> defects.csv (``run`` and ``measure``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.geometry import WallGrid
from pipestitch.io.outputs import DEFECT_COLUMNS, mosaic_from_uint8, read_mosaic, write_csv
from pipestitch.io.tiles import read_column_blocks
from pipestitch.measure.blocks import BlockDefects
from pipestitch.measure.defects import Defect
from pipestitch.pipeline.staging import finish_interrupted_commit, out_lock

__all__ = ["measure_mosaic", "measure_run", "write_defects_csv"]


def measure_mosaic(image: np.ndarray, grid: WallGrid, *,
                   crown_theta_deg: float = 270.0) -> list[Defect]:
    """Defects of a float mosaic, measured by blocks along z as ``run`` measures its
    streamed mosaic (:class:`pipestitch.measure.blocks.BlockDefects`; one block for up
    to ~2500 columns).

    Parameters
    ----------
    image : numpy.ndarray, shape grid.shape
        The mosaic (float, NaN = no data).
    grid : WallGrid
        Its grid (SPEC's), on the pipe's wall.
    crown_theta_deg : float, optional
        Theta of 12 o'clock (default: the relative reference, the first frame's image up).

    Returns
    -------
    list of Defect
        Sorted by z.
    """
    finder = BlockDefects(grid, up_theta_deg=crown_theta_deg)
    finder.push(0, image)
    return finder.finish()


def write_defects_csv(path: Path, defects: list[Defect], *,
                      reference: str = "relative") -> Path:
    """defects.csv: SPEC's columns first (kind, z_mm, theta_deg, clock, diameter_mm,
    area_mm2), then the bounding box, contrast, confidence, the partial flag and
    ``clock_reference`` (which reference the clock column uses)."""
    rows = [[getattr(d, c) if c != "partial" else int(d.partial) for c in DEFECT_COLUMNS]
            + [reference] for d in defects]
    return write_csv(path, (*DEFECT_COLUMNS, "clock_reference"), rows)


def measure_run(out: str | Path, *, crown_deg: float | None = None) -> tuple[Path, list[Defect]]:
    """``pipestitch measure OUT``: defects of an existing run's mosaic -> OUT/defects.csv.

    ``crown_deg``: mosaic theta of 12 o'clock (``--crown-deg``); default relative. The
    standards stage (``pipeline/coding.py``) re-references the clocks when the run
    has an IMU or a detected invert. An impossible mosaic.json (a scale <= 0, a NaN
    origin, a missing key) raises DatasetError naming the file and the key before
    anything is written (:func:`pipestitch.io.outputs.read_mosaic`).
    """
    out = Path(out)
    with out_lock(out, "measure"):
        return _measure(out, crown_deg)


def _measure(out: Path, crown_deg: float | None) -> tuple[Path, list[Defect]]:
    finish_interrupted_commit(out)
    image, meta = read_mosaic(out)
    crown = 270.0 if crown_deg is None else crown_deg
    full = meta.get("full_resolution")
    if isinstance(full, dict) and (out / str(full.get("file"))).is_file():
        pyramid = out / str(full["file"])
        n_rows, n_cols = _pyramid_shape(pyramid)
        grid = _grid(out, full, meta["radius_mm"], n_cols, n_rows=n_rows)
        defects = _measure_pyramid(pyramid, grid, crown)
    else:   # a mosaic.png without a pyramid (made elsewhere): it is the full resolution
        grid = _grid(out, meta, meta["radius_mm"], image.shape[1], n_rows=image.shape[0])
        defects = measure_mosaic(image, grid, crown_theta_deg=crown)
    reference = "relative" if crown_deg is None else "user (--crown-deg)"
    return write_defects_csv(out / "defects.csv", defects, reference=reference), defects


def _grid(out: Path, record: dict, radius_mm: float, n_cols: int, *,
          n_rows: int | None = None) -> WallGrid:
    """The grid a mosaic.json record (the overview's or ``full_resolution``) describes
    (:meth:`WallGrid.from_json`); DatasetError naming mosaic.json when it describes none."""
    try:
        return WallGrid.from_json(record, max(1, int(n_cols)), n_rows=n_rows,
                                  radius_mm=float(radius_mm))
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(out / "mosaic.json", f"mosaic grid: {exc}") from None


def _pyramid_shape(path: Path) -> tuple[int, int]:
    """Rows and columns of the full-resolution level of a mosaic pyramid (its header)."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            shape = tif.series[0].levels[0].shape
        return int(shape[0]), int(shape[1])
    except (OSError, ValueError, IndexError, tifffile.TiffFileError) as exc:
        raise DatasetError(path, f"unreadable mosaic pyramid: {exc}") from None


def _measure_pyramid(path: Path, grid: WallGrid, crown_deg: float) -> list[Defect]:
    """Defects of the full-resolution mosaic in ``path`` on ``grid``, read a tile column
    at a time and measured by blocks as ``run`` does (pipeline/stitched_output.py)."""
    try:
        finder = BlockDefects(grid, up_theta_deg=crown_deg)
        for col0, block in read_column_blocks(path):
            finder.push(col0, mosaic_from_uint8(block))
        return finder.finish()
    except (KeyError, TypeError, ValueError, OSError) as exc:
        raise DatasetError(path, f"unreadable mosaic pyramid: {exc}") from None
