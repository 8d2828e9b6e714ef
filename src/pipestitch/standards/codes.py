"""Survey metadata as the exchange formats code it: pipe material, section shape and the
direction of survey, by plain names (the names ``survey.toml`` takes), with their EN
13508-2 inspection-header codes and their PACP 7 codes.

Sources and what is verified: docs/standards.md, "What was verified against what". The
EN letters come from the code tables shipped with the public EN 13508-2 reader
kwb.en13508.2 (tables C4 material, AEC/ACA shape). The PACP deformation classes follow a
public PACP code table: rigid (``DR``) for asbestos cement, cast iron, concrete,
reinforced concrete and vitrified clay; flexible (``DF...``) for plastics (PVC),
reinforced plastic and corrugated metal. Steel and ductile iron are in neither list, so
their class is not stated (coded ``DR`` with a note). PACP's material and shape codes
themselves were not checked against the PACP 7 manual. Brick and masonry (PACP ``DT...``)
are left out: a small-bore pipe is never brick.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["DIRECTIONS", "MATERIALS", "SHAPES", "Material", "continuous_pacp",
           "deformation_pacp"]


@dataclass(frozen=True)
class Material:
    """A pipe material: EN 13508-2 ACD code, PACP 7 material code and whether PACP
    counts it as rigid (deformation ``DR``) or flexible (``DF...``); None = the source
    does not say (or the material is not known)."""

    en: str
    pacp: str
    rigid: bool | None


MATERIALS: dict[str, Material] = {
    "asbestos-cement": Material("AA", "AC", True),
    "vitrified-clay": Material("AE", "VCP", True),
    "concrete": Material("AG", "CP", True),
    "reinforced-concrete": Material("AH", "RCP", True),
    "fibre-cement": Material("AK", "AC", True),
    "grp": Material("AL", "FRP", False),
    "cast-iron": Material("AM", "CAS", True),
    "ductile-iron": Material("AO", "DIP", None),
    "steel": Material("AP", "SP", None),
    "polyester": Material("AU", "FRP", False),
    "polyethylene": Material("AV", "PE", False),
    "polypropylene": Material("AW", "PP", False),
    "pvc": Material("AX", "PVC", False),
    "plastic": Material("AY", "ZZZ", False),
    "unknown": Material("AZ", "XXX", None),
    "other": Material("Z", "ZZZ", None),
}

# name -> (EN 13508-2 ACA letter, PACP 7 shape code)
SHAPES: dict[str, tuple[str, str]] = {
    "circular": ("A", "C"), "rectangular": ("B", "R"), "egg": ("C", "E"),
    "u-shaped": ("D", "U"), "arch": ("E", "A"), "oval": ("F", "O"), "other": ("Z", "Z"),
}

# name -> (EN 13508-2 AAK letter, PACP 7 Direction); downstream = with the flow
DIRECTIONS: dict[str, tuple[str, str]] = {"downstream": ("A", "D"), "upstream": ("B", "U")}

_MARKER = re.compile(r"([ABSF])(\d+)", re.ASCII)


def deformation_pacp(material: str) -> tuple[str, str]:
    """PACP 7 deformation code for a pipe of ``material`` and a note for the remark.

    Parameters
    ----------
    material : str
        A name of :data:`MATERIALS` (or "" when not stated).

    Returns
    -------
    tuple of str
        ``("DR", "")`` for a rigid pipe, ``("DFE", "")`` (flexible, elliptical: the
        section compressed into an oval, which is what an ovality measures) for a
        flexible one; a material whose class is not known is coded ``DR`` and the note
        says why.
    """
    known = MATERIALS.get(material)
    if known is None or material in ("unknown", "other"):
        return "DR", "material not known: coded as rigid"
    if known.rigid is None:
        return "DR", f"PACP deformation class of {material} not verified: coded as rigid"
    return ("DR", "") if known.rigid else ("DFE", "")


def continuous_pacp(marker: str) -> str:
    """An EN 13508-2 continuous marker as PACP writes it.

    Parameters
    ----------
    marker : str
        ``A<n>``/``B<n>`` (EN 13508-2) or ``S<n>``/``F<n>`` (PACP).

    Returns
    -------
    str
        ``S<n>`` for a start, ``F<n>`` for a finish, ``n`` without leading zeros (the
        form public PACP documentation shows, e.g. ``S2``/``F2``); "" for anything else.
    """
    found = _MARKER.fullmatch(marker.strip())
    if found is None:
        return ""
    return {"A": "S", "B": "F"}.get(found[1], found[1]) + str(int(found[2]))
