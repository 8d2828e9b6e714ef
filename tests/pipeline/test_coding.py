"""The standards stage on real runs: clock positions against the simulator's truth after
the IMU reference, re-export of an edited observations.csv, --crown-deg, bad imu.csv,
invert detection on a mosaic with a sediment band, and the report."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.io.outputs import mosaic_to_uint8, write_json, write_mosaic_png
from pipestitch.pipeline.coding import code_run
from pipestitch.pipeline.review import render_review_page
from pipestitch.report.html import ReportData, render_report
from pipestitch.standards import clock_hour, parse_en13508, parse_json, parse_pacp_csv

runner = CliRunner()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory, simulate_small) -> Path:
    return simulate_small(tmp_path_factory.mktemp("std") / "ds", "--scenario", "test_piece",
                          "--pairs", "8", "--seed", "1")


@pytest.fixture(scope="module")
def output(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("std") / "out"
    result = runner.invoke(app, ["run", str(dataset), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_run_codes_observations_relative(output: Path) -> None:
    state = json.loads((output / "standards.json").read_text())
    assert state["reference"]["source"] == "relative"
    assert {r["clock_reference"] for r in _rows(output / "defects.csv")} == {"relative"}
    [(survey, obs)] = parse_en13508((output / "observations.txt").read_text("latin-1"))
    assert survey.reference == "relative" and survey.nominal_diameter_mm == 65
    assert sum(o.code == "BAC" for o in obs) >= 2
    # The test piece is round: where a section's ovality is measured it is far below the
    # 1 % coding threshold (0.1 %: a few times the oval fit's own scatter), so no BAA.
    assert not any(o.code == "BAA" for o in obs)
    for row in _rows(output / "ovality.csv"):
        q = float(row["f1216_mean_min_pct"])
        assert np.isnan(q) or 0 <= q < 0.1
    html = (output / "report.html").read_text()
    assert "Coded observations" in html and "reference: relative" in html


def test_imu_reference_gives_the_true_clock_positions(dataset: Path, output: Path,
                                                      tmp_path: Path) -> None:
    """With the simulator's true roll as the IMU (its pipe frame taken as +y down), each
    hole's clock is that of the true hole it matches, and its distance is the true one
    (mosaic start and z reference offsets removed) to the 0.01 m of the standard."""
    ds, out = tmp_path / "ds", tmp_path / "out"
    shutil.copytree(dataset, ds)
    shutil.copytree(output, out)
    truth_poses = _rows(ds / "truth" / "poses.csv")
    (ds / "imu.csv").write_text("frame,roll_deg\n" + "".join(
        f"{r['frame']},{r['roll_deg']}\n" for r in truth_poses))
    result = runner.invoke(app, ["export", str(out), "--dataset", str(ds), "--format", "json"])
    assert result.exit_code == 0, result.output
    survey, obs = parse_json((out / "observations.json").read_text())
    assert survey.reference == "imu"
    est = {r["frame"]: float(r["z_mm"]) for r in _rows(out / "poses.csv")}
    z_off = np.median([float(r["z_mm"]) - est[r["frame"]] for r in truth_poses])
    z0 = json.loads((out / "mosaic.json").read_text())["z0_mm"]
    truth = [r for r in _rows(ds / "truth" / "defects.csv") if r["kind"] == "hole"]
    defects = _rows(out / "defects.csv")
    holes = [o for o in obs if o.code == "BAC"]
    assert len(holes) >= 2
    for o in holes:
        d = defects[int(o.ref.split()[0][len("auto:D"):]) - 1]
        z_true = float(d["z_mm"]) + z_off
        match = min(truth, key=lambda t: abs(float(t["z_mm"]) - z_true)
                    + abs((float(t["theta_deg"]) - _gravity(out, d) + 180) % 360 - 180))
        assert abs(float(match["z_mm"]) - z_true) < 1.0
        assert o.clock_from == clock_hour(float(match["theta_deg"]))
        assert o.distance_m == pytest.approx((float(match["z_mm"]) - z_off - z0) / 1000,
                                             abs=0.0051)
        assert d["clock_reference"] == "imu"


def test_a_run_with_an_imu_gives_the_pipe_frames_roll_and_theta(dataset: Path,
                                                                  tmp_path: Path) -> None:
    """imu.csv is SPEC's reference for roll: poses.csv's roll_deg is then gamma against
    gravity (not relative), and the mosaic's theta the pipe frame's, crown at 270."""
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    truth_poses = _rows(ds / "truth" / "poses.csv")
    (ds / "imu.csv").write_text("frame,roll_deg\n" + "".join(
        f"{r['frame']},{r['roll_deg']}\n" for r in truth_poses))
    result = runner.invoke(app, ["run", str(ds), "--out", str(tmp_path / "out"), "--quiet"])
    assert result.exit_code == 0, result.output
    est = {r["frame"]: r["roll_deg"] for r in _rows(tmp_path / "out" / "poses.csv")}
    errors = [float(est[r["frame"]]) - float(r["roll_deg"]) for r in truth_poses
              if est[r["frame"]] != "nan"]
    assert len(errors) >= len(truth_poses) - 2 and max(map(abs, errors)) < 0.3
    meta = json.loads((tmp_path / "out" / "mosaic.json").read_text())
    assert meta["theta_reference"].startswith("imu")
    state = json.loads((tmp_path / "out" / "standards.json").read_text())
    assert state["reference"]["source"] == "imu"
    assert abs((state["reference"]["crown_theta_deg"] - 270 + 180) % 360 - 180) < 0.3
    truth = [float(r["theta_deg"]) for r in _rows(ds / "truth" / "defects.csv")
             if r["kind"] == "hole"]
    for d in _rows(tmp_path / "out" / "defects.csv"):
        if d["kind"] == "hole" and d["partial"] == "0":
            near = min(abs((float(d["theta_deg"]) - t + 180) % 360 - 180) for t in truth)
            assert near < 1.0   # deg: the mosaic's theta is the wall's


def _gravity(out: Path, defect: dict[str, str]) -> float:
    crown = json.loads((out / "standards.json").read_text())["reference"]["crown_theta_deg"]
    return (float(defect["theta_deg"]) - crown + 270) % 360


def test_user_rows_survive_recoding_with_crown_deg(output: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    shutil.copytree(output, out)
    with (out / "observations.csv").open("a") as handle:
        handle.write('0.05,BBC,Z,,,,"sediment, seen by eye",5,7,,my note\n')
    result = runner.invoke(app, ["export", str(out), "--crown-deg", "90", "--format",
                                 "pacp-csv", "--out", str(tmp_path / "survey.csv")])
    assert result.exit_code == 0, result.output
    obs = parse_pacp_csv((tmp_path / "survey.csv").read_text())
    assert [o.ref for o in obs if not o.ref.startswith("auto:")] == ["my note"]
    state = json.loads((out / "standards.json").read_text())
    assert state["reference"]["source"] == "user (--crown-deg)"
    # Crown moved from theta 270 to 90: every clock turns by 6 hours.
    before = {o["ref"]: int(o["clock_from"]) for o in _rows(output / "observations.csv")}
    for o in obs:
        if o.ref in before:
            assert o.clock_from == (before[o.ref] + 6 - 1) % 12 + 1


def test_bad_imu_file_is_named(dataset: Path, output: Path, tmp_path: Path) -> None:
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    (ds / "imu.csv").write_text("frame,roll_deg\n0,abc\n")
    result = runner.invoke(app, ["export", str(output), "--dataset", str(ds),
                                 "--out", str(tmp_path / "x.txt")])
    assert result.exit_code == 2
    assert "imu.csv" in result.output and "roll_deg" in result.output


def test_invert_detected_on_a_mosaic_with_a_sediment_band(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    rows, deg_per_px = 720, 0.5
    img = 100 + 10 * rng.standard_normal((rows, 400))
    theta = np.arange(rows) * deg_per_px
    invert = 123.0
    img[np.abs((theta - invert + 180) % 360 - 180) < 35] *= 0.55
    image_u8, _ = mosaic_to_uint8(img)
    write_mosaic_png(tmp_path / "mosaic.png", image_u8)
    write_json(tmp_path / "mosaic.json", {"mm_per_px_axial": 0.2, "deg_per_px": deg_per_px,
                                          "z0_mm": 0.0, "radius_mm": 32.5, "n_cols": 400})
    coded = code_run(tmp_path)
    assert coded.reference.source == "invert-detected"
    # Band drawn 70 deg wide around 123 deg; 8-bit quantisation and smoothing only.
    assert abs((coded.reference.crown_theta_deg - (invert + 180) + 180) % 360 - 180) < 1.0
    assert clock_hour(invert, coded.reference.crown_theta_deg) == 6


def test_oval_sections_are_coded_and_reported(tmp_path: Path) -> None:
    """profile.csv as the oval pose fit will write it: ovality measured from frame 10 on.
    Expected figures computed here from the radii, independently of the stage."""
    rows = ["frame,z_mm,diameter_mm,ovality,min_radius_mm,max_radius_mm,diameter_std_mm,"
            "model,within_tolerance"]
    for k in range(50):
        r_min, r_max = (32.5, 32.5) if k < 10 else (31.85, 33.15)
        ovality = "nan" if k < 10 else f"{(r_max - r_min) / 32.5:.6f}"
        model = "circle" if k < 10 else "ellipse"
        rows.append(f"{k},{10.0 * k:.6f},65.000000,{ovality},{r_min},{r_max},0.002,{model},1")
    (tmp_path / "profile.csv").write_text("\n".join(rows) + "\n")
    coded = code_run(tmp_path, nominal_diameter_mm=66.0)
    oval = _rows(tmp_path / "ovality.csv")
    assert oval[0]["f1216_mean_min_pct"] == "nan" and oval[0]["deflection_pct"] == "nan"
    assert float(oval[20]["f1216_mean_min_pct"]) == pytest.approx(100 * (65 - 63.7) / 65)
    assert float(oval[20]["f1216_max_mean_pct"]) == pytest.approx(100 * (66.3 - 65) / 65)
    assert float(oval[20]["range_nominal_pct"]) == pytest.approx(100 * 2.6 / 66)
    assert float(oval[20]["deflection_pct"]) == pytest.approx(100 * (66 - 63.7) / 66)
    baa = [o for o in coded.observations if o.code == "BAA"]
    # Frames 10..49 at 10 mm: 390 mm, shorter than EN's 1 m: one observation.
    assert [(o.continuous, o.distance_m) for o in baa] == [("", 0.10)]
    assert baa[0].quant1 == round(100 * (66 - 63.7) / 66)
    # With DWA's 0.3 m threshold: a start/finish pair from the first ring.
    dwa = code_run(tmp_path, nominal_diameter_mm=66.0, continuous_min_m=0.3)
    baa = [o for o in dwa.observations if o.code == "BAA"]
    assert [(o.continuous, o.distance_m) for o in baa] == [("A1", 0.10), ("B1", 0.49)]
    html = render_report(ReportData("t", None, 0.0, 1.0, 1.0, 66.0, [],
                                    standards=coded.report_view()))
    assert "ovality along the pipe" in html and "ASTM F1216 X1 ovality" in html


def test_export_bad_input_exits_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["export", str(tmp_path), "--format", "xml"])
    assert result.exit_code == 2 and "--format" in result.output
    result = runner.invoke(app, ["export", str(tmp_path)])
    assert result.exit_code == 2 and "not a run folder" in result.output
    (tmp_path / "poses.csv").write_text("frame,z_mm,roll_deg\n0,0,0\n")
    (tmp_path / "observations.csv").write_text("distance_m,code,clock_from\n0.1,BAC,13\n")
    result = runner.invoke(app, ["export", str(tmp_path), "--format", "json"])
    assert result.exit_code == 2
    assert "observations.csv" in result.output and "line 2" in result.output


def _mosaic_with_a_hole(folder: Path) -> None:
    """A 360 x 300 mosaic (1 deg, 0.5 mm per pixel) with one dark disc: one hole."""
    rng = np.random.default_rng(0)
    img = 100 + 3 * rng.standard_normal((360, 300))
    yy, xx = np.mgrid[:360, :300]
    img[(yy - 100) ** 2 + (xx - 150) ** 2 < 15 ** 2] = 10
    write_mosaic_png(folder / "mosaic.png", mosaic_to_uint8(img)[0])
    write_json(folder / "mosaic.json", {"mm_per_px_axial": 0.5, "deg_per_px": 1.0,
                                        "z0_mm": 0.0, "radius_mm": 30.0, "n_cols": 300})


OBS_HEADER = "distance_m,code,char1,char2,quant1,quant2,remark,clock_from,clock_to,continuous,ref"
USER_ROWS = ["1.23456,BDB,,,,,precise distance,,,,mine\n",
             "0.01,BAF,Z,,,,13 fields,3,,,mine 2,extra,more\n",
             '0.9,BDB,,,,,"two\nlines, ""quoted""",,,,mine 3\n']


def test_measure_keeps_user_rows_byte_for_byte(tmp_path: Path) -> None:
    """`pipestitch measure` re-codes: the auto: rows are replaced, the user's rows stay
    exactly as typed (1.23456 is not rounded, the 13-field row keeps its extra fields)."""
    _mosaic_with_a_hole(tmp_path)
    (tmp_path / "observations.csv").write_text(
        OBS_HEADER + "\n0.5,BAC,B,,9,,old hole,3,,,auto:D1 stale\n" + "".join(USER_ROWS))
    result = runner.invoke(app, ["measure", str(tmp_path)])
    assert result.exit_code == 0, result.output
    text = (tmp_path / "observations.csv").read_text()
    assert all(row in text for row in USER_ROWS) and "stale" not in text
    lines = text.split("\n")
    assert lines[0] == OBS_HEADER and lines[1] == USER_ROWS[1].rstrip("\n")
    # The hole: 30 px (15 mm) across at column 150 (z = 75 mm), BAC B quantified by its
    # length along the pipe.
    distance, *fields = lines[2].split(",")[:5]
    assert float(distance) == pytest.approx(0.075, abs=0.0051)
    assert fields == ["BAC", "B", "", "15"] and "auto:D1 mosaic" in lines[2]
    # Measuring again changes nothing.
    result = runner.invoke(app, ["measure", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "observations.csv").read_text() == text


def test_recoding_keeps_crlf_rows_and_header(tmp_path: Path) -> None:
    earlier = (OBS_HEADER + ",inspector\r\n" + "1.23456,BDB,,,,,note,,,,mine,Ann\r\n").encode()
    (tmp_path / "observations.csv").write_bytes(earlier)
    coded = code_run(tmp_path)
    assert (tmp_path / "observations.csv").read_bytes() == earlier
    assert [o.distance_m for o in coded.observations] == [1.23]


@pytest.mark.parametrize(("text", "message"), [
    (OBS_HEADER + "\n1.0,BDB,,,,,note,13,,,mine\n", "line 2: clock_from"),
    ("code,distance_m,ref\nBDB,1.0,mine\n", "line 1: the columns"),
    (OBS_HEADER + "\n1.0,B-B,,,,,,,,,mine\n", "line 2: code"),
])
def test_measure_refuses_user_rows_it_cannot_keep(tmp_path: Path, text: str,
                                                  message: str) -> None:
    _mosaic_with_a_hole(tmp_path)
    (tmp_path / "observations.csv").write_text(text)
    result = runner.invoke(app, ["measure", str(tmp_path)])
    assert result.exit_code == 2
    assert "observations.csv" in result.output and message in result.output
    assert (tmp_path / "observations.csv").read_text() == text


def test_observations_csv_not_utf8_is_named(tmp_path: Path) -> None:
    (tmp_path / "observations.csv").write_bytes(OBS_HEADER.encode() + b"\n1.0,BDB,,,,,\xe9,,,,x\n")
    result = runner.invoke(app, ["export", str(tmp_path)])
    assert result.exit_code == 2 and "observations.csv" in result.output
    assert "not UTF-8" in result.output


def test_the_run_s_overview_in_memory_codes_and_reviews_as_the_file_does(
        output: Path, dataset: Path, tmp_path: Path) -> None:
    """`pipestitch run` hands the overview it wrote to the coding and the review page
    instead of decoding mosaic.png again: the same reference, observations and page."""
    out = tmp_path / "out"
    shutil.copytree(output, out)
    overview = cv2.imread(str(out / "mosaic.png"), cv2.IMREAD_UNCHANGED)
    from_file = code_run(out, dataset=dataset)
    page = render_review_page(out)
    (out / "mosaic.png").unlink()   # now only the array can give the pixels
    in_memory = code_run(out, dataset=dataset, overview=overview)
    assert in_memory.reference == from_file.reference
    assert in_memory.observations == from_file.observations
    assert render_review_page(out, overview=overview) == page


def test_observations_csv_saved_by_a_spreadsheet_keeps_its_header(tmp_path: Path) -> None:
    """Excel's "CSV UTF-8" begins with a byte-order mark and ends lines with CRLF: the
    header is still read as the columns (the user's row is kept, the mark with it, so
    the spreadsheet reopens the file as UTF-8) and exported."""
    _mosaic_with_a_hole(tmp_path)
    user = "1.23456,BDB,,,,,Jürgen's note,,,,mine\r\n"
    (tmp_path / "observations.csv").write_bytes(
        b"\xef\xbb\xbf" + (OBS_HEADER + "\r\n" + user).encode("utf-8"))
    result = runner.invoke(app, ["measure", str(tmp_path)])
    assert result.exit_code == 0, result.output
    data = (tmp_path / "observations.csv").read_bytes()
    assert data.startswith(b"\xef\xbb\xbf" + OBS_HEADER.encode() + b"\r\n")
    assert user.encode("utf-8") in data and b"auto:D1" in data
    result = runner.invoke(app, ["export", str(tmp_path), "--format", "json"])
    assert result.exit_code == 0, result.output
    exported = json.loads((tmp_path / "observations.json").read_text(encoding="utf-8"))
    assert [o["code"] for o in exported["observations"]] == ["BAC", "BDB"]
    assert exported["observations"][1]["remark"] == "Jürgen's note"
