"""The measurement stage: defects on the mosaic -> defects.csv (``run`` and ``measure``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipestitch.io.outputs import DEFECT_COLUMNS, read_mosaic, write_csv
from pipestitch.measure.defects import Defect, MosaicGeometry, find_defects

__all__ = ["measure_mosaic", "measure_run", "write_defects_csv"]


def measure_mosaic(image: np.ndarray, deg_per_px: float, mm_per_px: float, z0_mm: float,
                   radius_mm: float, *, crown_theta_deg: float = 270.0) -> list[Defect]:
    """Defects of a float mosaic (NaN = no data) on SPEC's grid; clock 12 at
    ``crown_theta_deg`` (default: the relative reference, the first frame's image up)."""
    return find_defects(image, MosaicGeometry(deg_per_px, mm_per_px, z0_mm, radius_mm),
                        up_theta_deg=crown_theta_deg)


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
    standards stage (``pipeline/standards.py``) re-references the clocks when the run
    has an IMU or a detected invert.
    """
    out = Path(out)
    image, meta = read_mosaic(out)
    defects = measure_mosaic(image, meta["deg_per_px"], meta["mm_per_px_axial"], meta["z0_mm"],
                             meta["radius_mm"],
                             crown_theta_deg=270.0 if crown_deg is None else crown_deg)
    reference = "relative" if crown_deg is None else "user (--crown-deg)"
    return write_defects_csv(out / "defects.csv", defects, reference=reference), defects
