"""The exchange files as receiving software reads them.

EN 13508-2: checked by rules written here from what the public reader kwb.en13508.2
(KWB-R) documents and enforces: continuous defect codes in J match ``^$|^[AB]\\d+$``;
the #C captions are field letters it knows (A..N), unique, the same in every block; D,
E and I are numbers, G and H whole numbers; every #B01 line is followed by one value line
with as many fields; the #A1..#A6 file header is present. And what the standard asks
of an inspection: BCD first, BCE last, the header codes a receiving system needs.

PACP 7: the tables' exact column names, the codes (holes H, deformation by material,
continuous S/F) and the units: metric and imperial both read back to the same records.
"""

from __future__ import annotations

import csv
import io
import math
import re
import typing
from dataclasses import dataclass, replace

import pytest

from pipestitch.io import survey_toml
from pipestitch.standards import (
    DIRECTIONS,
    DWA_CONTINUOUS_MIN_M,
    MATERIALS,
    SHAPES,
    Observation,
    PacpCondition,
    Survey,
    crown_from_invert,
    en_markers,
    observations_from_defects,
    observations_from_profile,
    pacp_conditions,
    parse_en13508,
    parse_pacp7_tables,
    relative_reference,
    with_nodes,
    write_en13508,
    write_pacp7_tables,
)
from pipestitch.standards.observations import ProfileSection
from pipestitch.standards.ovality import SectionFigures

# --- the public reader's rules, as checks of our own --------------------------------------

KNOWN_LETTERS = set("ABCDEFGHIJKLMN")
# Inspection header codes of the package's code table (eucodes.csv, tables C1, C2, C3,
# C5), the ones marked "not used" left out.
KNOWN_HEADER_CODES = ({f"AA{c}" for c in "ABCDEFGHIJKLMNOPQ"}
                      | {f"AB{c}" for c in "ABCEFGHIJKLMNOPQRST"}
                      | {f"AC{c}" for c in "ABCDEFGHIJKLMN"} | {f"AD{c}" for c in "ABCE"})
NUMERIC, INTEGER = set("DEI"), set("GH")
MARKER = re.compile(r"^$|^[AB]\d+$")


def en_problems(text: str) -> list[str]:
    """Every way ``text`` breaks the rules above (empty: the reader takes it)."""
    lines = [line for line in text.split("\n") if line.strip()]
    meta = dict(line[1:].split("=", 1) for line in lines if line.startswith("#A"))
    problems = [f"#{k} missing" for k in ("A1", "A2", "A3", "A4", "A5", "A6") if k not in meta]
    sep, quote = meta.get("A3", ";"), meta.get("A5", '"')
    captions: list[str] | None = None
    for k, line in enumerate(lines):
        if line.startswith("#B01="):
            codes = line[5:].split(sep)
            problems += [f"line {k + 1}: unknown header code {c}" for c in codes
                         if c not in KNOWN_HEADER_CODES]
            nxt = lines[k + 1] if k + 1 < len(lines) else "#"
            if nxt.startswith("#") or len(_cells(nxt, sep, quote)) != len(codes):
                problems.append(f"line {k + 1}: #B01 not followed by {len(codes)} values")
        elif line.startswith("#C="):
            found = line[3:].split(sep)
            if captions is not None and found != captions:
                problems.append(f"line {k + 1}: #C captions differ between blocks")
            captions = found
            if set(found) - KNOWN_LETTERS or len(set(found)) != len(found):
                problems.append(f"line {k + 1}: unknown or repeated captions {found}")
        elif not line.startswith("#") and captions is not None and lines[k - 1][:4] != "#B01":
            problems += [f"line {k + 1}: {p}" for p in _row_problems(
                dict(zip(captions, _cells(line, sep, quote), strict=False)))]
    return problems


def _cells(line: str, sep: str, quote: str) -> list[str]:
    return next(csv.reader([line], delimiter=sep, quotechar=quote))


def _row_problems(row: dict[str, str]) -> list[str]:
    out = []
    for letter, value in row.items():
        if value and letter in NUMERIC and not re.fullmatch(r"-?\d+(\.\d+)?", value):
            out.append(f"{letter} = {value!r} is not a number")
        if value and letter in INTEGER and not re.fullmatch(r"\d+", value):
            out.append(f"{letter} = {value!r} is not a whole number")
    if not MARKER.match(row.get("J", "")):
        out.append(f"J = {row['J']!r} does not match {MARKER.pattern}")
    return out


def _en_rows(text: str) -> list[dict[str, str]]:
    lines = text.split("\n")
    letters = next(line[3:].split(";") for line in lines if line.startswith("#C="))
    start = lines.index("#C=" + ";".join(letters)) + 1
    end = lines.index("#Z")
    return [dict(zip(letters, _cells(line, ";", '"'), strict=True)) for line in lines[start:end]]


def _header(text: str) -> dict[str, str]:
    lines = text.split("\n")
    k = next(i for i, line in enumerate(lines) if line.startswith("#B01="))
    return dict(zip(lines[k][5:].split(";"), _cells(lines[k + 1], ";", '"'), strict=True))


def test_the_checks_catch_what_the_reader_refuses() -> None:
    """The rule checks are not vacuous: each broken rule is reported."""
    good = write_en13508([(SURVEY, [Observation(1.0, "BAC", "B", quant1=5, clock_from=3)])])
    assert en_problems(good) == []
    assert any("J =" in p for p in en_problems(good.replace("1.00;BAC;B;;5;;;3;;;",
                                                            "1.00;BAC;B;;5;;;3;;S01;")))
    assert any("G =" in p for p in en_problems(good.replace(";5;;;3;", ";5;;;3.5;")))
    assert any("captions" in p for p in en_problems(good.replace("#C=I;A;", "#C=I;X;")))
    assert any("#A6" in p for p in en_problems(good.replace("#A6=2010\n", "")))
    assert any("header code" in p for p in en_problems(good.replace("#B01=AAA;", "#B01=XXX;")))


# --- a run with holes, a deformation and a continuous feature ---------------------------------

@dataclass
class _Defect:
    kind: str
    z_mm: float
    theta_deg: float
    diameter_mm: float
    area_mm2: float
    z_min_mm: float
    z_max_mm: float
    theta_min_deg: float
    theta_max_deg: float
    partial: bool = False


SURVEY = Survey("P-12", "2026-11-23", "14:30", 3.0, 65, "invert-detected",
                start_node="MH1", finish_node="MH2", direction="downstream",
                reference_point="Z", shape="circular", material="pvc", operator="A. Inspector",
                location="Test street; lot 4")
DEFECTS = [_Defect("hole", 400.0, 100.0, 6.0, 28.3, 397.0, 403.0, 95.0, 105.0),
           _Defect("hole", 900.0, 280.0, 8.0, 50.2, 896.0, 904.5, 275.0, 285.0),
           _Defect("spot", 1700.0, 90.0, 30.0, 700.0, 1200.0, 2300.0, 60.0, 120.0)]


def _oval(frame: int, z_mm: float, axis_theta: float) -> ProfileSection:
    return ProfileSection(frame, z_mm, 65.0, 63.0, 67.0,
                          SectionFigures(3.0, 3.0, 6.2, 3.1), axis_theta)


def _run(reference=None, axis_theta: float = 0.0) -> list[Observation]:
    reference = reference or crown_from_invert(90.0)      # crown at mosaic theta 270
    obs = observations_from_defects(DEFECTS, reference, 0.0)
    sections = [_oval(k, 2500.0 + 10 * k, axis_theta) for k in range(5)]
    obs += observations_from_profile(sections, 0.0, reference=reference,
                                     first_continuous=1 + sum(o.continuous.startswith("A")
                                                              for o in obs))
    return with_nodes(SURVEY, obs)


def test_en_file_of_a_run_passes_the_reader_rules() -> None:
    text = write_en13508([(SURVEY, _run())])
    assert en_problems(text) == []
    rows = _en_rows(text)
    assert rows[0]["A"] == "BCD" and rows[-1]["A"] == "BCE"
    assert float(rows[-1]["I"]) == SURVEY.length_m
    assert [r["A"] for r in rows[1:-1]] == ["BAC", "BAC", "BBB", "BBB", "BAA"]
    # The 1.1 m spot is longer than EN's 1 m: a continuous pair A1 ... B1.
    assert [r["J"] for r in rows if r["J"]] == ["A1", "B1"]
    # Holes: BAC B quantified by their length along the pipe (mm, below 1000).
    assert [(r["B"], r["D"]) for r in rows if r["A"] == "BAC"] == [("B", "6"), ("B", "8")]
    # The deformation, with a roll reference (detected invert): oriented, A or B.
    [baa] = [r for r in rows if r["A"] == "BAA"]
    assert baa["B"] in ("A", "B") and baa["D"] == "3"
    header = _header(text)
    assert {k: header[k] for k in ("AAB", "AAK", "ABC", "ACA", "ACD", "ABF", "ABH")} == {
        "AAB": "MH1", "AAK": "A", "ABC": "Z", "ACA": "A", "ACD": "AX", "ABF": "2026-11-23",
        "ABH": "A. Inspector"}
    # Direction A (downstream): the inspection starts at node 2, as in the example file.
    assert (header["AAF"], header["AAD"]) == ("MH1", "MH2")
    [(survey, back)] = parse_en13508(text)
    assert survey == SURVEY and back == _run()


@pytest.mark.parametrize(("axis_theta", "char1"), [(0.0, "A"), (180.0, "A"), (270.0, "B"),
                                                   (100.0, "B"), (40.0, "A")])
def test_baa_is_oriented_by_the_roll_reference(axis_theta: float, char1: str) -> None:
    """Crown at mosaic theta 270: a major axis at theta 0/180 is horizontal, so the
    vertical diameter is the short one (A, vertical); at 270 or 100 it is near vertical
    (B, horizontal deformation)."""
    [baa] = [o for o in _run(axis_theta=axis_theta) if o.code == "BAA"]
    assert baa.char1 == char1


def test_baa_orientation_unknown_without_a_roll_reference() -> None:
    [baa] = [o for o in _run(relative_reference()) if o.code == "BAA"]
    assert baa.char1 == "" and "unknown" in baa.remark
    [baa] = [o for o in _run(axis_theta=math.nan) if o.code == "BAA"]
    assert baa.char1 == "" and "not measured" in baa.remark


def test_nodes_are_added_once_and_legacy_markers_converted() -> None:
    obs = [Observation(0.5, "BAF", "Z", "E", continuous="S03"),
           Observation(1.5, "BAF", "Z", "E", continuous="F03")]
    framed = with_nodes(SURVEY, en_markers(obs))
    assert [(o.code, o.continuous) for o in framed] == [("BCD", ""), ("BAF", "A3"),
                                                        ("BAF", "B3"), ("BCE", "")]
    assert with_nodes(SURVEY, framed) == framed
    numbered = with_nodes(replace(SURVEY, start_node="17"), obs)
    assert numbered[0].quant1 == 17 and "17" in numbered[0].remark


def test_a_header_without_metadata_is_the_fixed_one() -> None:
    plain = Survey("p", "2026-01-02", "03:04", 5.0, 100, "relative")
    assert list(_header(write_en13508([(plain, [])]))) == [
        "AAA", "ABA", "ABF", "ABG", "ABQ", "ACB", "ACC", "ADE"]
    with pytest.raises(ValueError, match="material"):
        Survey("p", "2026-01-02", "03:04", 5.0, 100, "relative", material="brick")


# --- PACP 7 --------------------------------------------------------------------------------------

CONDITIONS = ("ConditionID, InspectionID, Distance, Counter, PACP_Code, Continuous, "
              "Value_1st_Dimension, Value_2nd_Dimension, Value_Percent, Joint, Clock_At_From, "
              "Clock_To, Remarks, VCR_Time").split(", ")


def _tables(units: str, material: str = "pvc") -> dict[str, str]:
    survey = replace(SURVEY, material=material)
    return write_pacp7_tables(survey, pacp_conditions(_run(), material=material), units=units)


def _csv(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text, newline="")))


def test_pacp_tables_have_pacps_names_and_codes() -> None:
    tables = _tables("metric")
    assert set(tables) == {"PACP_Inspections", "PACP_Conditions", "PACP_Media_Conditions"}
    assert tables["PACP_Conditions"].split("\n", 1)[0].split(",") == CONDITIONS
    rows = _csv(tables["PACP_Conditions"])
    codes = [r["PACP_Code"] for r in rows]
    assert codes.count("H") == 2 and "DFE" in codes          # PVC is flexible
    assert [r["Continuous"] for r in rows if r["Continuous"]] == ["S1", "F1"]
    deformation = next(r for r in rows if r["PACP_Code"] == "DFE")
    assert deformation["Value_Percent"] == "3" and deformation["Value_1st_Dimension"] == ""
    [head] = _csv(tables["PACP_Inspections"])
    assert (head["IsImperial"], head["Upstream_MH"], head["Direction"]) == ("0", "MH1", "D")
    assert (head["Material"], head["Shape"], head["Height"]) == ("PVC", "C", "65")
    media = _csv(tables["PACP_Media_Conditions"])
    assert {m["ConditionID"] for m in media} <= {r["ConditionID"] for r in rows}
    assert all(m["Image_Reference"].startswith("auto:") for m in media) and media
    rigid = [r["PACP_Code"] for r in _csv(_tables("metric", "vitrified-clay")["PACP_Conditions"])]
    assert "DR" in rigid and "DFE" not in rigid
    unknown = _csv(_tables("metric", "unknown")["PACP_Conditions"])
    assert any(r["PACP_Code"] == "DR" and "material not known" in r["Remarks"] for r in unknown)


def test_pacp_imperial_is_in_feet_and_inches_and_both_round_trip() -> None:
    metric, imperial = _tables("metric"), _tables("imperial")
    [head] = _csv(imperial["PACP_Inspections"])
    assert head["IsImperial"] == "1"
    assert float(head["Height"]) == pytest.approx(65 / 25.4, abs=0.005)
    assert float(head["Length_Surveyed"]) == pytest.approx(3.0 / 0.3048, abs=0.005)
    first_hole = next(r for r in _csv(imperial["PACP_Conditions"]) if r["PACP_Code"] == "H")
    assert float(first_hole["Distance"]) == pytest.approx(0.4 / 0.3048, abs=0.005)
    assert float(first_hole["Value_1st_Dimension"]) == pytest.approx(6 / 25.4, abs=0.005)
    # PACP_Inspections has no field for EN's longitudinal reference point (ABC).
    expected = (replace(SURVEY, reference_point=""), pacp_conditions(_run(), material="pvc"))
    assert parse_pacp7_tables(metric) == expected
    assert parse_pacp7_tables(imperial) == expected


@pytest.mark.parametrize("distance_m", [0.0, 0.01, 0.15, 1.23, 99.99, 1234.56])
def test_imperial_distances_read_back_exactly(distance_m: float) -> None:
    """0.01 ft (3 mm) is finer than the 0.01 m a record holds: no rounding drift."""
    conditions = [PacpCondition(distance_m, "H", value_1st_mm=round(distance_m * 100))]
    back = parse_pacp7_tables(write_pacp7_tables(SURVEY, conditions, units="imperial"))[1]
    assert back == conditions


def test_pacp_cells_are_neutralised_and_bad_tables_named() -> None:
    survey = replace(SURVEY, operator="=HYPERLINK(1)")
    tables = write_pacp7_tables(survey, [PacpCondition(1.0, "H", remarks="@SUM(1)",
                                                       image="+x")], units="metric")
    for text in tables.values():
        for row in csv.reader(io.StringIO(text, newline="")):
            assert not any(c.startswith(("=", "+", "@")) for c in row), row
    assert parse_pacp7_tables(tables)[0].operator == "=HYPERLINK(1)"
    assert parse_pacp7_tables(tables)[1][0].image == "+x"
    with pytest.raises(ValueError, match="IsImperial"):
        parse_pacp7_tables({**tables, "PACP_Inspections": tables["PACP_Inspections"].replace(
            ",0\n", ",yes\n")})
    with pytest.raises(ValueError, match="PACP_Conditions line 2"):
        parse_pacp7_tables({**tables, "PACP_Conditions": tables["PACP_Conditions"].replace(
            ",1.00,", ",x,")})
    with pytest.raises(ValueError, match="units"):
        write_pacp7_tables(SURVEY, [], units="furlongs")


def test_continuous_threshold_is_a_choice() -> None:
    """EN's 1 m by default; DWA's 0.3 m when chosen."""
    spot = [_Defect("spot", 1000.0, 90.0, 30.0, 700.0, 800.0, 1300.0, 60.0, 120.0)]
    en = observations_from_defects(spot, relative_reference(), 0.0)
    dwa = observations_from_defects(spot, relative_reference(), 0.0,
                                    continuous_min_m=DWA_CONTINUOUS_MIN_M)
    assert [o.continuous for o in en] == [""]
    assert [o.continuous for o in dwa] == ["A1", "B1"]


def test_survey_toml_names_match_the_code_tables() -> None:
    """survey.toml (io) validates the same names the standards tables code."""
    literals = {name: set(typing.get_args(getattr(survey_toml, name)))
                for name in ("Direction", "Shape", "Material")}
    assert literals == {"Direction": set(DIRECTIONS), "Shape": set(SHAPES),
                        "Material": set(MATERIALS)}
