"""Optional ``DATASET/survey.toml``: what the survey's exchange files and report say about
the pipe and the inspection (ids, nodes, direction, material, shape, date, operator,
location) and how observations are coded (continuous threshold, spots, PACP units).

Every key is optional; unknown keys and bad values are refused with a
:class:`~pipestitch.errors.ConfigError` naming the file and each problem, like
probe.toml. The names of ``direction``, ``shape`` and ``material`` are those of
``pipestitch.standards.codes`` (a test keeps the two lists equal).
"""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from pipestitch.io.probe_toml import validated_toml
from pipestitch.io.text import read_config_text

__all__ = ["SURVEY_FILE", "SurveyFile", "parse_survey_toml", "read_survey_toml"]

SURVEY_FILE = "survey.toml"

Direction = Literal["downstream", "upstream"]
Shape = Literal["circular", "rectangular", "egg", "u-shaped", "arch", "oval", "other"]
Material = Literal["asbestos-cement", "vitrified-clay", "concrete", "reinforced-concrete",
                   "fibre-cement", "grp", "cast-iron", "ductile-iron", "steel", "polyester",
                   "polyethylene", "polypropylene", "pvc", "plastic", "unknown", "other"]
_TIME = re.compile(r"^([01]\d|2[0-3]):[0-5]\d$")


class SurveyFile(BaseModel):
    """survey.toml, validated (None: not stated)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    pipe_ref: str | None = Field(None, min_length=1, max_length=200)
    start_node: str | None = Field(None, max_length=200)
    finish_node: str | None = Field(None, max_length=200)
    direction: Direction | None = None
    reference_point: str | None = Field(None, pattern=r"^[A-Z]$")
    shape: Shape | None = None
    material: Material | None = None
    date: dt.date | None = None
    time: str | None = None
    operator: str | None = Field(None, max_length=200)
    location: str | None = Field(None, max_length=500)
    continuous_min_m: float | None = Field(None, gt=0, le=1000, allow_inf_nan=False)
    spots: Literal["deposit", "surface-damage"] | None = None
    units: Literal["metric", "imperial"] | None = None

    @field_validator("time", mode="before")
    @classmethod
    def _time(cls, value: object) -> object:
        if isinstance(value, dt.time):
            return value.strftime("%H:%M")
        if isinstance(value, str) and not _TIME.match(value):
            raise ValueError(f"expected HH:MM, got {value!r}")
        return value

    @field_validator("date", mode="before")
    @classmethod
    def _date(cls, value: object) -> object:
        if isinstance(value, dt.datetime):
            raise ValueError("expected a date (YYYY-MM-DD), got a date and time")
        return value


def parse_survey_toml(text: str, path: str | Path = SURVEY_FILE) -> SurveyFile:
    """Parse and validate survey.toml text; ConfigError names ``path`` and every problem."""
    return validated_toml(text, Path(path), SurveyFile, sections=False)


def read_survey_toml(dataset: str | Path) -> SurveyFile | None:
    """``dataset/survey.toml`` validated, or None when the file is absent."""
    path = Path(dataset) / SURVEY_FILE
    if not path.is_file():
        return None
    return parse_survey_toml(read_config_text(path), path)
