"""DATASET/survey.toml: every key optional, unknown keys and bad values refused with the
file named (like probe.toml), and check_dataset reporting the same problems."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pytest

from pipestitch.errors import ConfigError
from pipestitch.io.dataset import check_dataset
from pipestitch.io.survey_toml import parse_survey_toml, read_survey_toml

FULL = """# a comment
pipe_ref = "P-12"
start_node = "MH1"
finish_node = "MH2"
direction = "downstream"
reference_point = "A"
shape = "circular"
material = "pvc"
date = 2026-11-23
time = "14:30"
operator = "A. Inspector"
location = "Test street"
continuous_min_m = 0.3
spots = "surface-damage"
units = "imperial"
"""


def test_a_full_file_is_read() -> None:
    s = parse_survey_toml(FULL)
    assert (s.pipe_ref, s.start_node, s.finish_node, s.direction) == ("P-12", "MH1", "MH2",
                                                                      "downstream")
    assert (s.material, s.shape, s.date, s.time) == ("pvc", "circular", dt.date(2026, 11, 23),
                                                     "14:30")
    assert (s.continuous_min_m, s.spots, s.units) == (0.3, "surface-damage", "imperial")
    # A TOML time is accepted too, as HH:MM.
    assert parse_survey_toml("time = 09:05:00").time == "09:05"
    assert parse_survey_toml("") == parse_survey_toml("# nothing stated")


@pytest.mark.parametrize(("text", "message"), [
    ('materail = "pvc"', "unknown key materail"),
    ('material = "brick"', "material"),
    ('direction = "sideways"', "direction"),
    ('time = "25:00"', "expected HH:MM"),
    ('date = "2026-13-01"', "date"),
    ("date = 2026-11-23T10:00:00", "a date and time"),
    ("continuous_min_m = 0", "continuous_min_m"),
    ("continuous_min_m = nan", "continuous_min_m"),
    ('units = "furlongs"', "units"),
    ('reference_point = "ab"', "reference_point"),
    ("[survey]\npipe_ref = 'x'", "unknown key survey"),
    ("pipe_ref = ", "malformed TOML"),
])
def test_bad_files_are_refused_naming_file_and_problem(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        parse_survey_toml(text, Path("/data/ds/survey.toml"))
    assert str(info.value).startswith("/data/ds/survey.toml: ")


def test_every_problem_is_listed_at_once() -> None:
    with pytest.raises(ConfigError) as info:
        parse_survey_toml('foo = 1\nmaterial = "x"\nunits = "y"')
    assert all(word in str(info.value) for word in ("unknown key foo", "material", "units"))


def test_absent_file_is_none_and_check_dataset_reports_a_bad_one(tmp_path: Path) -> None:
    assert read_survey_toml(tmp_path) is None
    (tmp_path / "survey.toml").write_text('shape = "hexagon"\n')
    problems = [p for p in check_dataset(tmp_path) if p.path.name == "survey.toml"]
    assert len(problems) == 1 and "shape" in problems[0].message
    (tmp_path / "survey.toml").write_bytes(b"operator = '\xe9'\n")
    with pytest.raises(ConfigError, match=r"survey\.toml"):
        read_survey_toml(tmp_path)
