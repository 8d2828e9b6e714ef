"""PACP 7 exchange tables (NASSCO's Pipeline Assessment Certification Program) as CSV
files named after the tables of the exchange database: write and parse.

``PACP_Inspections`` (one row: the survey header, ``IsImperial`` saying the units),
``PACP_Conditions`` (one row per condition, PACP's column names exactly),
``PACP_Media_Conditions`` (the image reference of each condition that has one) and,
only when the caller passes ratings computed from graded conditions,
``PACP_Ratings`` (:mod:`pipestitch.standards.pacp_ratings`; pipestitch assigns no
grades itself).

Units: metric (``IsImperial`` 0) writes distances and lengths in m, dimensions and the
pipe size in mm; imperial (1) in feet and inches, to 0.01. Both read back to the same
records (:func:`parse_pacp7_tables` returns metric values; 0.01 ft and 0.01 in are
finer than the 0.01 m and 1 mm the records hold).

Codes come from the EN 13508-2 observations (:func:`pacp_conditions`): holes ``H``,
deformation ``DR``/``DFE`` by the pipe material, attached deposits ``DAE``/``DAGS``/
``DAZ``, settled deposits ``DSF``/``DSGV``/``DSC``/``DSZ``, surface damage ``SZ``,
continuous markers ``S<n>``/``F<n>``; anything else is a general observation ``MGO``
whose remark names the EN code. The table and column names are those public importers
of PACP 7 CSV exports use and the codes are in public PACP code tables; neither was
checked against the PACP 7 manual (docs/standards.md). Text cells are neutralised
against formula injection as in the other CSV exports
(:func:`pipestitch.standards.observations.neutralise_cell`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from pipestitch.standards.codes import (
    DIRECTIONS,
    MATERIALS,
    SHAPES,
    continuous_pacp,
    deformation_pacp,
)
from pipestitch.standards.observations import (
    Observation,
    Survey,
    csv_record,
    csv_records,
    format_cell,
    neutralise_cell,
    parse_int,
    restore_cell,
)
from pipestitch.standards.pacp_ratings import PacpRatings, write_pacp_ratings

__all__ = ["CONDITION_COLUMNS", "INSPECTION_COLUMNS", "MEDIA_COLUMNS", "RATINGS_TABLE", "TABLES",
           "PacpCondition", "pacp_conditions", "parse_pacp7_tables", "write_pacp7_tables"]

INSPECTION_ID = 1
INSPECTION_COLUMNS = ("InspectionID", "Surveyed_By", "Pipe_Segment_Reference",
                      "Inspection_Date", "Inspection_Time", "Location_Details",
                      "Upstream_MH", "Downstream_MH", "Direction", "Height", "Width", "Shape",
                      "Material", "Length_Surveyed", "Additional_Info", "IsImperial")
CONDITION_COLUMNS = ("ConditionID", "InspectionID", "Distance", "Counter", "PACP_Code",
                     "Continuous", "Value_1st_Dimension", "Value_2nd_Dimension",
                     "Value_Percent", "Joint", "Clock_At_From", "Clock_To", "Remarks",
                     "VCR_Time")
MEDIA_COLUMNS = ("ConditionID", "Image_Reference")
TABLES = ("PACP_Inspections", "PACP_Conditions", "PACP_Media_Conditions")
RATINGS_TABLE = "PACP_Ratings"

FT_M = 0.3048
IN_MM = 25.4
REFERENCE_PREFIX = "clock reference: "
_TEXT_INSPECTION = frozenset({"Surveyed_By", "Pipe_Segment_Reference", "Location_Details",
                              "Upstream_MH", "Downstream_MH", "Additional_Info",
                              "Inspection_Date", "Inspection_Time"})
_TEXT_CONDITION = frozenset({"PACP_Code", "Continuous", "Remarks"})
# EN 13508-2 (code, characterisation 1) -> PACP 7 deposit codes
_DEPOSITS = {("BBB", "A"): "DAE", ("BBB", "B"): "DAGS", ("BBC", "A"): "DSF",
             ("BBC", "B"): "DSGV", ("BBC", "C"): "DSC"}


@dataclass(frozen=True)
class PacpCondition:
    """One PACP_Conditions row (metric: distance in m to 0.01, dimensions in mm)."""

    distance_m: float
    code: str
    continuous: str = ""
    value_1st_mm: int | None = None
    value_2nd_mm: int | None = None
    value_percent: int | None = None
    clock_from: int | None = None
    clock_to: int | None = None
    remarks: str = ""
    image: str = ""

    def __post_init__(self) -> None:
        if not math.isfinite(self.distance_m) or self.distance_m < 0:
            raise ValueError(f"Distance: expected a finite distance >= 0, got {self.distance_m}")
        object.__setattr__(self, "distance_m", round(float(self.distance_m), 2))
        if not self.code or not self.code.isalnum():
            raise ValueError(f"PACP_Code: expected a code such as H, got {self.code!r}")


def _pacp_code(o: Observation, material: str) -> tuple[str, str]:
    """(PACP 7 code, a note for the remark) of an EN 13508-2 observation."""
    if o.code == "BAC":
        return "H", ""
    if o.code == "BAA":
        return deformation_pacp(material)
    if o.code in ("BBB", "BBC"):
        return _DEPOSITS.get((o.code, o.char1), "DAZ" if o.code == "BBB" else "DSZ"), ""
    if o.code == "BAF":
        return "SZ", ""
    return "MGO", f"EN 13508-2 {' '.join(filter(None, (o.code, o.char1, o.char2)))}"


def pacp_conditions(observations: Iterable[Observation], *,
                    material: str = "") -> list[PacpCondition]:
    """The observations as PACP 7 conditions (deformation coded by ``material``, a name
    of :data:`~pipestitch.standards.codes.MATERIALS`; quantification 1 of a deformation
    goes to ``Value_Percent``, else to ``Value_1st_Dimension``)."""
    out = []
    for o in observations:
        code, note = _pacp_code(o, material)
        percent = o.code == "BAA"
        remark = "; ".join(filter(None, (o.remark, note)))
        out.append(PacpCondition(o.distance_m, code, continuous_pacp(o.continuous),
                                 None if percent else o.quant1, o.quant2,
                                 o.quant1 if percent else None, o.clock_from, o.clock_to,
                                 remark, o.ref))
    return out


def _length(value_m: float, imperial: bool) -> str:
    return "" if not math.isfinite(value_m) else f"{value_m / FT_M if imperial else value_m:.2f}"


def _size(value_mm: int | None, imperial: bool) -> str:
    if value_mm is None:
        return ""
    return f"{value_mm / IN_MM:.2f}" if imperial else str(value_mm)


def _row(columns: Sequence[str], values: Mapping[str, str], text: frozenset[str]) -> str:
    cells = [values.get(c, "") for c in columns]
    quoted = {i for i, c in enumerate(columns)
              if c in text and neutralise_cell(cells[i]) != cells[i]}
    return csv_record([neutralise_cell(c) if i in quoted else c for i, c in enumerate(cells)],
                      quoted)


def _inspection(survey: Survey, imperial: bool) -> dict[str, str]:
    upstream, downstream = survey.start_node, survey.finish_node
    if survey.direction == "upstream":
        upstream, downstream = downstream, upstream
    return {"InspectionID": str(INSPECTION_ID), "Surveyed_By": survey.operator,
            "Pipe_Segment_Reference": survey.pipe_ref, "Inspection_Date": survey.date,
            "Inspection_Time": survey.time, "Location_Details": survey.location,
            "Upstream_MH": upstream, "Downstream_MH": downstream,
            "Direction": DIRECTIONS[survey.direction][1] if survey.direction else "",
            "Height": _size(survey.nominal_diameter_mm, imperial),
            "Width": _size(survey.nominal_diameter_mm, imperial),
            "Shape": SHAPES[survey.shape][1] if survey.shape else "",
            "Material": MATERIALS[survey.material].pacp if survey.material else "",
            "Length_Surveyed": _length(survey.length_m, imperial),
            "Additional_Info": REFERENCE_PREFIX + survey.reference,
            "IsImperial": "1" if imperial else "0"}


def write_pacp7_tables(survey: Survey, conditions: Sequence[PacpCondition], *,
                       units: str = "metric",
                       ratings: PacpRatings | None = None) -> dict[str, str]:
    """CSV text per table for one inspection.

    Parameters
    ----------
    survey : Survey
        The inspection header.
    conditions : sequence of PacpCondition
        The conditions, in order (``ConditionID`` 1, 2, ...).
    units : str
        "metric" or "imperial" (``IsImperial``).
    ratings : PacpRatings, optional
        Ratings from graded conditions; adds the :data:`RATINGS_TABLE` table.

    Returns
    -------
    dict of str to str
        Table name (:data:`TABLES`, and :data:`RATINGS_TABLE` with ``ratings``) to CSV
        text.

    Raises
    ------
    ValueError
        For other units.
    """
    if units not in ("metric", "imperial"):
        raise ValueError(f"units: expected metric or imperial, got {units!r}")
    imperial = units == "imperial"
    conditions_csv = [csv_record(CONDITION_COLUMNS)]
    media = [csv_record(MEDIA_COLUMNS)]
    for k, c in enumerate(conditions, start=1):
        conditions_csv.append(_row(CONDITION_COLUMNS, {
            "ConditionID": str(k), "InspectionID": str(INSPECTION_ID),
            "Distance": _length(c.distance_m, imperial), "PACP_Code": c.code,
            "Continuous": c.continuous, "Value_1st_Dimension": _size(c.value_1st_mm, imperial),
            "Value_2nd_Dimension": _size(c.value_2nd_mm, imperial),
            "Value_Percent": format_cell(c.value_percent), "Clock_At_From": format_cell(
                c.clock_from), "Clock_To": format_cell(c.clock_to), "Remarks": c.remarks},
            _TEXT_CONDITION))
        if c.image:
            media.append(_row(MEDIA_COLUMNS, {"ConditionID": str(k), "Image_Reference": c.image},
                              frozenset({"Image_Reference"})))
    inspection = csv_record(INSPECTION_COLUMNS) + _row(
        INSPECTION_COLUMNS, _inspection(survey, imperial), _TEXT_INSPECTION)
    tables = dict(zip(TABLES, (inspection, "".join(conditions_csv), "".join(media)),
                      strict=True))
    if ratings is not None:
        tables[RATINGS_TABLE] = write_pacp_ratings(ratings, INSPECTION_ID)
    return tables


def _table(text: str, name: str, required: Sequence[str]) -> list[tuple[int, dict[str, str]]]:
    records = csv_records(text)
    _, _, columns = next(records, (1, "", []))
    missing = [c for c in required if c not in columns]
    if missing:
        raise ValueError(f"{name}: missing column(s) {', '.join(missing)}")
    return [(line, dict(zip(columns, (restore_cell(c) for c in cells), strict=False)))
            for line, _, cells in records if any(c.strip() for c in cells)]


def _metric_length(text: str, imperial: bool, what: str) -> float:
    try:
        value = float(text) if text.strip() else math.nan
    except ValueError:
        raise ValueError(f"{what} = {text!r} is not a number") from None
    return round(value * FT_M, 2) if imperial else value


def _metric_size(text: str, imperial: bool, what: str) -> int | None:
    if not imperial:
        return parse_int(text, what)
    try:
        return round(float(text) * IN_MM) if text.strip() else None
    except ValueError:
        raise ValueError(f"{what} = {text!r} is not a number") from None


def _name(table: Mapping, code: str, pick: object) -> str:
    return next((name for name, entry in table.items() if pick(entry) == code), "")


def _survey(row: dict[str, str], imperial: bool) -> Survey:
    direction = _name(DIRECTIONS, row.get("Direction", ""), lambda e: e[1])
    start, finish = row.get("Upstream_MH", ""), row.get("Downstream_MH", "")
    if direction == "upstream":
        start, finish = finish, start
    info = row.get("Additional_Info", "")
    size = _metric_size(row.get("Height", ""), imperial, "Height")
    return Survey(row.get("Pipe_Segment_Reference", ""), row.get("Inspection_Date", ""),
                  row.get("Inspection_Time", ""),
                  _metric_length(row.get("Length_Surveyed", ""), imperial, "Length_Surveyed"),
                  size or 0, info[len(REFERENCE_PREFIX):] if info.startswith(REFERENCE_PREFIX)
                  else "", start_node=start, finish_node=finish, direction=direction,
                  shape=_name(SHAPES, row.get("Shape", ""), lambda e: e[1]),
                  material=_name(MATERIALS, row.get("Material", ""), lambda e: e.pacp),
                  operator=row.get("Surveyed_By", ""), location=row.get("Location_Details", ""))


def _condition(row: dict[str, str], imperial: bool, image: str) -> PacpCondition:
    distance = _metric_length(row.get("Distance", ""), imperial, "Distance")
    return PacpCondition(distance, row.get("PACP_Code", "").strip(),
                         row.get("Continuous", "").strip(),
                         _metric_size(row.get("Value_1st_Dimension", ""), imperial,
                                      "Value_1st_Dimension"),
                         _metric_size(row.get("Value_2nd_Dimension", ""), imperial,
                                      "Value_2nd_Dimension"),
                         parse_int(row.get("Value_Percent", ""), "Value_Percent"),
                         parse_int(row.get("Clock_At_From", ""), "Clock_At_From"),
                         parse_int(row.get("Clock_To", ""), "Clock_To"),
                         row.get("Remarks", ""), image)


def parse_pacp7_tables(tables: Mapping[str, str]) -> tuple[Survey, list[PacpCondition]]:
    """Read the tables :func:`write_pacp7_tables` wrote (CSV text per table name; the
    media table is optional) back, in metric units. ValueError names the table, the
    line and the problem."""
    if "PACP_Inspections" not in tables:
        raise ValueError("PACP_Inspections: missing")
    rows = _table(tables["PACP_Inspections"], "PACP_Inspections", ("InspectionID", "IsImperial"))
    if not rows:
        raise ValueError("PACP_Inspections: no inspection row")
    head = rows[0][1]
    flag = head.get("IsImperial", "").strip().lower()
    if flag not in ("0", "1", "-1", "true", "false"):
        raise ValueError(f"PACP_Inspections: IsImperial = {flag!r}: expected 0 or 1")
    imperial = flag in ("1", "-1", "true")
    media = {row.get("ConditionID", ""): row.get("Image_Reference", "") for _, row in
             _table(tables.get("PACP_Media_Conditions", ""), "PACP_Media_Conditions", ())}
    out = []
    for line, row in _table(tables.get("PACP_Conditions", ""), "PACP_Conditions",
                            ("Distance", "PACP_Code")):
        try:
            out.append(_condition(row, imperial, media.get(row.get("ConditionID", ""), "")))
        except ValueError as exc:
            raise ValueError(f"PACP_Conditions line {line}: {exc}") from None
    try:
        return _survey(head, imperial), out
    except ValueError as exc:
        raise ValueError(f"PACP_Inspections: {exc}") from None
