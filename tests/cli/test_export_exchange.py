"""`pipestitch export` of the exchange formats on a small run folder: the EN 13508-2 file
(BCD ... BCE, A/B markers, survey.toml's header fields), the PACP 7 tables in both units,
the survey in the report, and bad survey.toml / --units refused with exit code 2."""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.io.outputs import DEFECT_COLUMNS
from pipestitch.pipeline.coding import code_run
from pipestitch.report.html import ReportData, render_report
from pipestitch.standards import parse_en13508, parse_pacp7_tables

runner = CliRunner()
SURVEY_TOML = """pipe_ref = "P-12"
start_node = "MH1"
finish_node = "MH2"
direction = "upstream"
material = "vitrified-clay"
date = 2026-11-23
time = "14:30"
operator = "A. Inspector"
location = "Test street"
"""


def _defect(kind: str, z0: float, z1: float, theta: float) -> list[object]:
    values = {"kind": kind, "z_mm": (z0 + z1) / 2, "theta_deg": theta, "clock": "3:00",
              "diameter_mm": 6.0, "area_mm2": 28.0, "z_min_mm": z0, "z_max_mm": z1,
              "theta_min_deg": theta - 5, "theta_max_deg": theta + 5, "contrast": -0.9,
              "confidence": 1.0, "partial": 0}
    return [values[c] for c in DEFECT_COLUMNS]


@pytest.fixture
def run_folder(tmp_path: Path) -> tuple[Path, Path]:
    """A run with two holes, a 1.5 m spot and a 0.39 m oval stretch (major axis at
    mosaic theta 0), and a dataset holding survey.toml."""
    out, ds = tmp_path / "out", tmp_path / "ds"
    out.mkdir()
    ds.mkdir()
    (ds / "survey.toml").write_text(SURVEY_TOML)
    (out / "poses.csv").write_text("frame,z_mm,roll_deg\n0,0,0\n")
    rows = [_defect("hole", 397, 403, 100), _defect("hole", 896, 904, 280),
            _defect("spot", 1200, 2700, 90)]
    with (out / "defects.csv").open("w", newline="") as handle:
        csv.writer(handle).writerows([DEFECT_COLUMNS, *rows])
    lines = ["frame,z_mm,diameter_mm,ovality,min_radius_mm,max_radius_mm,major_axis_theta_deg"]
    lines += [f"{k},{10 * k},65,0.06,31.5,33.5,0" for k in range(40)]
    (out / "profile.csv").write_text("\n".join(lines) + "\n")
    return out, ds


def _rows(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text, newline="")))


def test_en13508_export_carries_nodes_markers_and_survey(run_folder) -> None:
    out, ds = run_folder
    result = runner.invoke(app, ["export", str(out), "--dataset", str(ds), "--crown-deg", "270"])
    assert result.exit_code == 0, result.output
    text = (out / "observations.txt").read_bytes().decode("latin-1")
    [(survey, obs)] = parse_en13508(text)
    assert obs[0].code == "BCD" and obs[-1].code == "BCE"
    assert all(re.fullmatch(r"^$|^[AB]\d+$", o.continuous) for o in obs)
    assert [o.continuous for o in obs if o.continuous] == ["A1", "B1"]     # the 1.5 m spot
    assert [o.quant1 for o in obs if o.code == "BAC"] == [6, 8]
    # Major axis at theta 0 with the crown at 270: horizontal, so a vertical deformation.
    assert [o.char1 for o in obs if o.code == "BAA"] == ["A"]
    assert (survey.pipe_ref, survey.start_node, survey.finish_node) == ("P-12", "MH1", "MH2")
    assert (survey.direction, survey.material, survey.date) == ("upstream", "vitrified-clay",
                                                                "2026-11-23")
    assert "#B01=AAA;AAB;AAD;AAF;AAJ;AAK;ABA;ABC;ABF;ABG;ABH;ABQ;ACA;ACB;ACC;ACD;ADE" in text


def test_pacp7_export_in_both_units(run_folder, tmp_path: Path) -> None:
    out, ds = run_folder
    tables = {}
    for units in ("metric", "imperial"):
        dest = tmp_path / units
        result = runner.invoke(app, ["export", str(out), "--dataset", str(ds), "--format",
                                     "pacp7", "--units", units, "--out", str(dest)])
        assert result.exit_code == 0, result.output
        assert sorted(p.name for p in dest.iterdir()) == [
            "PACP_Conditions.csv", "PACP_Inspections.csv", "PACP_Media_Conditions.csv"]
        tables[units] = {p.stem: p.read_text() for p in dest.iterdir()}
    [metric_head] = _rows(tables["metric"]["PACP_Inspections"])
    [imperial_head] = _rows(tables["imperial"]["PACP_Inspections"])
    assert (metric_head["IsImperial"], imperial_head["IsImperial"]) == ("0", "1")
    # Upstream survey: it starts at the downstream manhole.
    assert (metric_head["Downstream_MH"], metric_head["Direction"]) == ("MH1", "U")
    codes = [r["PACP_Code"] for r in _rows(tables["metric"]["PACP_Conditions"])]
    assert codes.count("H") == 2 and "DR" in codes                # clay is rigid
    assert parse_pacp7_tables(tables["metric"]) == parse_pacp7_tables(tables["imperial"])
    # The default folder, units from the run's coding (metric).
    result = runner.invoke(app, ["export", str(out), "--format", "pacp7"])
    assert result.exit_code == 0, result.output
    assert (out / "pacp7" / "PACP_Conditions.csv").is_file()


def test_survey_is_in_the_report(run_folder) -> None:
    out, ds = run_folder
    coded = code_run(out, dataset=ds)
    html = render_report(ReportData("t", None, 0.0, 1.0, 1.0, 65.0, [],
                                    standards=coded.report_view()))
    assert "<h2>Survey</h2>" in html
    assert all(v in html for v in ("P-12", "MH1", "MH2", "vitrified-clay", "A. Inspector"))


@pytest.mark.parametrize(("toml", "args", "message"), [
    ('materail = "pvc"\n', [], "unknown key materail"),
    ('direction = "sideways"\n', [], "direction"),
    (SURVEY_TOML, ["--units", "furlongs"], "--units"),
])
def test_bad_survey_or_units_exit_2(run_folder, toml: str, args: list[str],
                                    message: str) -> None:
    out, ds = run_folder
    (ds / "survey.toml").write_text(toml)
    result = runner.invoke(app, ["export", str(out), "--dataset", str(ds), "--format",
                                 "pacp7", *args])
    assert result.exit_code == 2, result.output
    assert message in result.output
    if not args:
        assert "survey.toml" in result.output
    assert "Traceback" not in result.output
