"""Ovality and deflection of a pipe section by their named definitions.

All in percent, from the section's mean, minimum and maximum inside diameters (and a
nominal/base inside diameter). Sources and clauses: docs/standards.md.

* ``f1216_mean_min``: ASTM F1216 appendix X1 ovality, 100 (mean ID - min ID) / mean ID;
* ``f1216_max_mean``: the same appendix's other form, 100 (max ID - mean ID) / mean ID;
* ``range_nominal``: 100 (max ID - min ID) / nominal ID;
* ``deflection``: 100 (base ID - min ID) / base ID, base = the nominal inside diameter;
* ``spec``: SPEC's profile.csv ovality, (max ID - min ID) / mean ID, as a fraction.

A section measured with the circle model has no minimum or maximum diameter of its own
(min = max by construction): every figure is then NaN, never a fake 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["DEFINITIONS", "SectionFigures", "section_figures"]

DEFINITIONS: dict[str, str] = {
    "f1216_mean_min_pct": "ASTM F1216 X1 ovality: 100·(mean ID − min ID)/mean ID",
    "f1216_max_mean_pct": "ASTM F1216 X1 ovality (max form): 100·(max ID − mean ID)/mean ID",
    "range_nominal_pct": "100·(max ID − min ID)/nominal ID",
    "deflection_pct": "deflection: 100·(base ID − min ID)/base ID, base = nominal ID",
}


@dataclass(frozen=True)
class SectionFigures:
    """Named ovality/deflection figures of one section (percent; NaN = not measured)."""

    f1216_mean_min_pct: float
    f1216_max_mean_pct: float
    range_nominal_pct: float
    deflection_pct: float


def section_figures(mean_id_mm: float, min_id_mm: float, max_id_mm: float,
                    nominal_id_mm: float, *, measured: bool = True) -> SectionFigures:
    """The named figures of a section.

    Parameters
    ----------
    mean_id_mm, min_id_mm, max_id_mm : float
        Mean, minimum and maximum inside diameter of the section (mm).
    nominal_id_mm : float
        Nominal (base) inside diameter (mm).
    measured : bool
        False when min/max were not measured (circle model): all figures are NaN.
    """
    nan = math.nan
    values = (mean_id_mm, min_id_mm, max_id_mm)
    if not measured or not all(math.isfinite(v) and v > 0 for v in values):
        return SectionFigures(nan, nan, nan, nan)
    base_ok = math.isfinite(nominal_id_mm) and nominal_id_mm > 0
    return SectionFigures(
        f1216_mean_min_pct=100 * (mean_id_mm - min_id_mm) / mean_id_mm,
        f1216_max_mean_pct=100 * (max_id_mm - mean_id_mm) / mean_id_mm,
        range_nominal_pct=100 * (max_id_mm - min_id_mm) / nominal_id_mm if base_ok else nan,
        deflection_pct=100 * (nominal_id_mm - min_id_mm) / nominal_id_mm if base_ok else nan)
