"""The measurement stage: defects on the mosaic -> defects.csv (``run`` and ``measure``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipestitch.io.outputs import DEFECT_COLUMNS, read_mosaic, write_csv
from pipestitch.measure.defects import Defect, MosaicGeometry, find_defects

__all__ = ["measure_mosaic", "measure_run", "write_defects_csv"]


def measure_mosaic(image: np.ndarray, deg_per_px: float, mm_per_px: float, z0_mm: float,
                   radius_mm: float) -> list[Defect]:
    """Defects of a float mosaic (NaN = no data) on SPEC's grid."""
    return find_defects(image, MosaicGeometry(deg_per_px, mm_per_px, z0_mm, radius_mm))


def write_defects_csv(path: Path, defects: list[Defect]) -> Path:
    """defects.csv: SPEC's columns first (kind, z_mm, theta_deg, clock, diameter_mm,
    area_mm2), then the bounding box, contrast, confidence and the partial flag."""
    rows = [[getattr(d, c) if c != "partial" else int(d.partial) for c in DEFECT_COLUMNS]
            for d in defects]
    return write_csv(path, DEFECT_COLUMNS, rows)


def measure_run(out: str | Path) -> tuple[Path, list[Defect]]:
    """``pipestitch measure OUT``: defects of an existing run's mosaic -> OUT/defects.csv."""
    out = Path(out)
    image, meta = read_mosaic(out)
    defects = measure_mosaic(image, meta["deg_per_px"], meta["mm_per_px_axial"], meta["z0_mm"],
                             meta["radius_mm"])
    return write_defects_csv(out / "defects.csv", defects), defects
