"""PACP-style CSV: pipestitch's own one-file CSV with a PACP code column: write and parse.

Not the PACP exchange database (that is :mod:`pipestitch.standards.pacp7`, the tables
PACP_Inspections, PACP_Conditions, ... with PACP's column names): one CSV row per
observation, metric units (distance in m, dimensions in mm) and the EN 13508-2 code
columns alongside, so the file re-imports without loss. The PACP code is a translation
of the EN code (``PACP_CODES``), not verified against the PACP manual (docs/standards.md).

The file is meant for spreadsheets: text cells (codes, characterisations, continuous
code, remark, image reference) that begin with ``=``, ``+``, ``-``, ``@``, tab or CR
are written with a ``'`` in front and quoted, against formula injection (OWASP "CSV
Injection"); :func:`parse_pacp_csv` takes that ``'`` off again, so the round trip is
exact (:func:`pipestitch.standards.observations.neutralise_cell`). Numeric columns are
written from numbers and stay plain numbers (``-3``), never prefixed.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable

from pipestitch.standards.observations import (
    Observation,
    csv_record,
    csv_records,
    format_cell,
    neutralise_cell,
    observation_from_fields,
    restore_cell,
)

__all__ = ["PACP_CODES", "PACP_COLUMNS", "parse_pacp_csv", "write_pacp_csv"]

# (EN main code, characterisation 1) -> PACP-style code; unverified (see module doc).
PACP_CODES = {("BAC", "B"): "H", ("BAF", "Z"): "SZ", ("BAA", ""): "DR", ("BAA", "A"): "DR",
              ("BAA", "B"): "DR", ("BBB", "Z"): "DAZ", ("BBC", "Z"): "DSZ"}
PACP_COLUMNS = ("Distance_m", "Code", "Continuous", "Value_1st_Dimension_mm",
                "Value_2nd_Dimension_mm", "Value_Percent", "Clock_At_From", "Clock_To",
                "Remarks", "Image_Reference", "EN13508_Code", "EN13508_Char1", "EN13508_Char2")
PERCENT_CODES = {"BAA"}          # codes whose quantification 1 is a percentage
TO_FIELDS = {"Distance_m": "distance_m", "Continuous": "continuous",
             "Clock_At_From": "clock_from", "Clock_To": "clock_to", "Remarks": "remark",
             "Image_Reference": "ref", "EN13508_Code": "code", "EN13508_Char1": "char1",
             "EN13508_Char2": "char2", "Value_2nd_Dimension_mm": "quant2"}


# Columns that hold text (neutralised against formula injection); the others are numbers.
TEXT_COLUMNS = frozenset({"Code", "Continuous", "Remarks", "Image_Reference", "EN13508_Code",
                          "EN13508_Char1", "EN13508_Char2"})


def write_pacp_csv(observations: Iterable[Observation]) -> str:
    """The PACP-style CSV text (text cells neutralised, see the module docstring)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(PACP_COLUMNS)
    text = [i for i, c in enumerate(PACP_COLUMNS) if c in TEXT_COLUMNS]
    for o in observations:
        percent = o.code in PERCENT_CODES
        cell = format_cell
        cells = [cell(o.distance_m), PACP_CODES.get((o.code, o.char1), o.code),
                 o.continuous, "" if percent else cell(o.quant1), cell(o.quant2),
                 cell(o.quant1) if percent else "", cell(o.clock_from),
                 cell(o.clock_to), o.remark, o.ref, o.code, o.char1, o.char2]
        quoted = {i for i in text if neutralise_cell(cells[i]) != cells[i]}
        buffer.write(csv_record([neutralise_cell(c) if i in quoted else c
                                 for i, c in enumerate(cells)], quoted))
    return buffer.getvalue()


def parse_pacp_csv(text: str) -> list[Observation]:
    """Read the PACP-style CSV back (neutralised cells restored); ValueError names the
    line and the problem."""
    records = csv_records(text)
    _, _, columns = next(records, (1, "", []))
    missing = [c for c in ("Distance_m", "EN13508_Code") if c not in columns]
    if missing:
        raise ValueError(f"missing column(s) {', '.join(missing)}")
    out = []
    for line, _, cells in records:
        if not cells:
            continue
        row = dict(zip(columns, (restore_cell(c) for c in cells), strict=False))
        values = {name: row.get(col) or "" for col, name in TO_FIELDS.items()}
        quant = "Value_Percent" if values["code"] in PERCENT_CODES else "Value_1st_Dimension_mm"
        values["quant1"] = row.get(quant) or ""
        try:
            out.append(observation_from_fields(values))
        except ValueError as exc:
            raise ValueError(f"line {line}: {exc}") from None
    return out
