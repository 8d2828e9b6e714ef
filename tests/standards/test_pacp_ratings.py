"""PACP_Ratings: the rating method on a published worked example, the table's exact
columns, the round trip through our parser, and metric/imperial exports alike.

The worked example is the "Sample Grading Matrix" of Lucity's PACP help page
(help.lucity.com, "Grading System Example"): occurrences per grade 1-5, structural
1, 3, 2, 5, 3 and O&M 3, 5, 4, 0, 2, giving the ratings 48 (structural), 35 (O&M) and
83 (overall) over 14, 14 and 28 occurrences, and the overall quick rating 5545.
"""

from __future__ import annotations

import csv
import io

import pytest

from pipestitch.standards import (
    ConditionGrade,
    PacpCondition,
    PacpRatings,
    Survey,
    pacp_ratings,
    parse_pacp7_tables,
    parse_pacp_ratings,
    write_pacp7_tables,
)
from pipestitch.standards.codes import continuous_pacp, deformation_pacp
from pipestitch.standards.pacp_ratings import RATING_COLUMNS, write_pacp_ratings

# PACP 7 PACP_Ratings columns as a public InfoAsset Manager export script inserts them
# (RatingID is the table's AutoNumber key and is not written).
COLUMNS = ("InspectionID STGradeScore1 STGradeScore2 STGradeScore3 STGradeScore4 "
           "STGradeScore5 OMGradeScore1 OMGradeScore2 OMGradeScore3 OMGradeScore4 "
           "OMGradeScore5 STPipeRating OMPipeRating OverallPipeRating STQuickRating "
           "OMQuickRating PACPQuickRating STPipeRatingsIndex OMPipeRatingsIndex "
           "OverallPipeRatingsIndex LoFPACP").split()

STRUCTURAL, OM = (1, 3, 2, 5, 3), (3, 5, 4, 0, 2)


def _example_grades() -> list[ConditionGrade]:
    """The worked example as conditions: one per occurrence, except a continuous grade-4
    structural defect counting 3 occurrences."""
    grades = [ConditionGrade(structural=4, occurrences=3)]
    counts = {"structural": list(STRUCTURAL), "om": list(OM)}
    counts["structural"][3] -= 3
    for kind, per_grade in counts.items():
        for grade, n in enumerate(per_grade, start=1):
            grades += [ConditionGrade(**{kind: grade})] * n
    return grades


def _row(text: str) -> dict[str, str]:
    return next(csv.DictReader(io.StringIO(text, newline="")))


def test_ratings_of_the_published_example() -> None:
    ratings = pacp_ratings(_example_grades())
    assert (ratings.structural, ratings.om) == (STRUCTURAL, OM)
    assert [ratings.rating(k) for k in ("structural", "om", "overall")] == [48, 35, 83]
    assert [ratings.quick(k) for k in ("structural", "om", "overall")] == [
        "5345", "5234", "5545"]
    assert ratings.index("structural") == pytest.approx(48 / 14)
    assert ratings.index("overall") == pytest.approx(83 / 28)
    row = _row(write_pacp_ratings(ratings))
    assert tuple(row) == RATING_COLUMNS == tuple(COLUMNS)
    assert [row[f"STGradeScore{g}"] for g in range(1, 6)] == ["1", "6", "6", "20", "15"]
    assert (row["OverallPipeRating"], row["PACPQuickRating"]) == ("83", "5545")
    assert (row["STPipeRatingsIndex"], row["OMPipeRatingsIndex"]) == ("3.43", "2.50")
    assert row["LoFPACP"] == ""


def test_quick_rating_edge_cases() -> None:
    assert PacpRatings().quick("overall") == "0000"
    assert PacpRatings(structural=(0, 2, 0, 0, 0)).quick("structural") == "2200"
    assert PacpRatings().index("om") is None
    # More than 9 occurrences: PACP's form for that was not checked, so nothing is written.
    assert PacpRatings(om=(0, 0, 12, 0, 0)).quick("om") == ""
    with pytest.raises(ValueError, match="grade"):
        ConditionGrade(structural=6)
    with pytest.raises(ValueError, match="occurrences"):
        ConditionGrade(om=2, occurrences=0)


def test_ratings_round_trip_in_both_units() -> None:
    ratings = pacp_ratings(_example_grades())
    survey = Survey("P-12", "2026-11-23", "14:30", 3.0, 65, "imu", material="pvc")
    conditions = [PacpCondition(0.4, "H", value_1st_mm=6)]
    metric = write_pacp7_tables(survey, conditions, units="metric", ratings=ratings)
    imperial = write_pacp7_tables(survey, conditions, units="imperial", ratings=ratings)
    # Ratings have no units: both exports carry the same table.
    assert metric["PACP_Ratings"] == imperial["PACP_Ratings"]
    assert parse_pacp_ratings(metric["PACP_Ratings"]) == ratings
    assert parse_pacp7_tables(imperial) == parse_pacp7_tables(metric)
    # Without grades there is no ratings table.
    assert "PACP_Ratings" not in write_pacp7_tables(survey, conditions)


def test_bad_ratings_tables_are_named() -> None:
    text = write_pacp_ratings(pacp_ratings(_example_grades()))
    with pytest.raises(ValueError, match="PACP_Ratings: STGradeScore2 = 7"):
        parse_pacp_ratings(text.replace("\n1,1,6,", "\n1,1,7,"))
    with pytest.raises(ValueError, match="STPipeRating = 47"):
        parse_pacp_ratings(text.replace(",48,35,83,", ",47,35,83,"))
    with pytest.raises(ValueError, match="no row"):
        parse_pacp_ratings(text.split("\n")[0] + "\n")


@pytest.mark.parametrize(("material", "code", "note"), [
    ("vitrified-clay", "DR", ""), ("concrete", "DR", ""), ("pvc", "DFE", ""),
    ("polyethylene", "DFE", ""), ("steel", "DR", "steel not verified"),
    ("ductile-iron", "DR", "ductile-iron not verified"), ("", "DR", "material not known"),
    ("unknown", "DR", "material not known")])
def test_deformation_code_by_material(material: str, code: str, note: str) -> None:
    found, remark = deformation_pacp(material)
    assert found == code and note in remark and bool(note) == bool(remark)


@pytest.mark.parametrize(("marker", "pacp"), [("A1", "S1"), ("B12", "F12"), ("S01", "S1"),
                                              ("F03", "F3"), ("X1", ""), ("", "")])
def test_continuous_markers_as_pacp_writes_them(marker: str, pacp: str) -> None:
    assert continuous_pacp(marker) == pacp

