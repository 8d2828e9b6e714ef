"""Inspection standards: clock positions with a roll reference, named ovality and
deflection definitions, coded observations and their exchange formats.

Pure (no file access): :mod:`pipestitch.pipeline.coding` reads a run folder and writes
what these functions return. See docs/standards.md. May import ``geometry``,
``jsonsafe``, ``errors``; must not import ``io``, ``pipeline``, ``cli`` or ``config``.
"""

from pipestitch.standards.en13508 import parse_en13508, write_en13508
from pipestitch.standards.invert import InvertBand, detect_invert
from pipestitch.standards.jsonfmt import parse_json, write_json_text
from pipestitch.standards.observations import (
    CONTINUOUS_MIN_M,
    Observation,
    Survey,
    observations_from_defects,
    observations_from_profile,
    parse_observations_csv,
    write_observations_csv,
)
from pipestitch.standards.ovality import DEFINITIONS, SectionFigures, section_figures
from pipestitch.standards.pacp import parse_pacp_csv, write_pacp_csv
from pipestitch.standards.roll_reference import (
    RollReference,
    clock_hhmm,
    clock_hour,
    crown_from_imu,
    crown_from_invert,
    relative_reference,
    user_reference,
)

__all__ = ["CONTINUOUS_MIN_M", "DEFINITIONS", "InvertBand", "Observation", "RollReference",
           "SectionFigures", "Survey", "clock_hhmm", "clock_hour", "crown_from_imu",
           "crown_from_invert", "detect_invert", "observations_from_defects",
           "observations_from_profile", "parse_en13508", "parse_json",
           "parse_observations_csv", "parse_pacp_csv", "relative_reference", "section_figures",
           "user_reference", "write_en13508", "write_json_text", "write_observations_csv",
           "write_pacp_csv"]
