"""Inspection standards: clock positions with a roll reference, named ovality and
deflection definitions, coded observations and their exchange formats.

Pure (no file access): :mod:`pipestitch.pipeline.coding` reads a run folder and writes
what these functions return. See docs/standards.md. May import ``geometry``,
``jsonsafe``, ``errors``; must not import ``io``, ``pipeline``, ``cli`` or ``config``.
"""

from pipestitch.standards.codes import DIRECTIONS, MATERIALS, SHAPES
from pipestitch.standards.en13508 import parse_en13508, write_en13508
from pipestitch.standards.invert import InvertBand, detect_invert
from pipestitch.standards.jsonfmt import parse_json, write_json_text
from pipestitch.standards.observations import (
    CONTINUOUS_MIN_M,
    DWA_CONTINUOUS_MIN_M,
    SPOT_CODINGS,
    Observation,
    Survey,
    en_markers,
    observations_from_defects,
    observations_from_profile,
    parse_observations_csv,
    with_nodes,
    write_observations_csv,
)
from pipestitch.standards.ovality import DEFINITIONS, SectionFigures, section_figures
from pipestitch.standards.pacp import parse_pacp_csv, write_pacp_csv
from pipestitch.standards.pacp7 import (
    PacpCondition,
    pacp_conditions,
    parse_pacp7_tables,
    write_pacp7_tables,
)
from pipestitch.standards.pacp_ratings import (
    ConditionGrade,
    PacpRatings,
    pacp_ratings,
    parse_pacp_ratings,
)
from pipestitch.standards.roll_reference import (
    RollReference,
    clock_hhmm,
    clock_hour,
    crown_from_imu,
    crown_from_invert,
    relative_reference,
    user_reference,
)

__all__ = ["CONTINUOUS_MIN_M", "DEFINITIONS", "DIRECTIONS", "DWA_CONTINUOUS_MIN_M", "MATERIALS",
           "SHAPES", "SPOT_CODINGS", "ConditionGrade", "InvertBand", "Observation",
           "PacpCondition", "PacpRatings", "RollReference", "SectionFigures", "Survey",
           "clock_hhmm", "clock_hour", "crown_from_imu", "crown_from_invert", "detect_invert",
           "en_markers", "observations_from_defects", "observations_from_profile",
           "pacp_conditions", "pacp_ratings", "parse_en13508", "parse_json",
           "parse_observations_csv", "parse_pacp7_tables", "parse_pacp_csv",
           "parse_pacp_ratings", "relative_reference", "section_figures", "user_reference",
           "with_nodes", "write_en13508", "write_json_text", "write_observations_csv",
           "write_pacp7_tables", "write_pacp_csv"]
