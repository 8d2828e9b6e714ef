"""EN 13508-2 text exchange file: write and parse.

Layout (EN 13508-2 annex on data transfer; checked against a published example file,
docs/standards.md): a file header of ``#A<n>=`` lines (A1 character set, A2 language,
A3 field separator, A4 decimal mark, A5 quote character, A6 format version), then per
inspection a header block ``#B01=<codes>`` with one line of values, an observation
block ``#C=<field letters>`` with one line per observation, and ``#Z`` closing it.

Observation field letters used: I distance (m), A main code, B/C characterisation 1/2,
D/E quantification 1/2, F remark, G/H circumferential location (clock hour at/from, to),
J continuous defect code (``A<n>`` start, ``B<n>`` end), M photograph reference (our
mosaic/frame reference). Inspection header codes used: AAA pipe reference, ABA
standard, ABF date, ABG time, ABQ anticipated length (m), ACB height, ACC width (mm),
ADE general remark (which carries the clock reference); and, when the survey states
them, AAB start node, AAD/AAF node 1/2, AAJ location, AAK direction, ABC longitudinal
reference point, ABH inspector, ACA shape, ACD material. Node 1/2 follow the published
example file: with AAK = A the inspection starts at node 2, with B at node 1.

The parser reads any field order and separator the ``#A`` lines declare, ignores
fields it does not know (e.g. K joint, N video reference) and returns one
(Survey, observations) pair per inspection.

Field values cannot break the file's structure (the format is line based: a line
beginning with ``#`` is a control line, fields are split at the A3 separator):

* control characters (C0 and C1, tab, CR and LF included) and the Unicode line and
  paragraph separators in a value are written as spaces: the only lossy step, and the
  only one needed, since the format has no escape for a line break;
* a value holding the separator ``;`` or the quote character ``"`` is quoted with the
  A5 quote character (quotes doubled), the format's own mechanism, read back exactly;
* a value that begins with ``#`` (after spaces) is quoted too, so no line begins with
  ``#`` unless it is one of the writer's control lines; read back exactly.

So any text without control characters round-trips exactly.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Sequence

from pipestitch.standards.codes import DIRECTIONS, MATERIALS, SHAPES
from pipestitch.standards.observations import Observation, Survey, parse_int

__all__ = ["field_text", "parse_en13508", "write_en13508"]

OBS_FIELDS = {"I": "distance_m", "A": "code", "B": "char1", "C": "char2", "D": "quant1",
              "E": "quant2", "F": "remark", "G": "clock_from", "H": "clock_to",
              "J": "continuous", "M": "ref"}
HEADER_FIELDS = {"AAA": "pipe_ref", "ABA": "standard", "ABF": "date", "ABG": "time",
                 "ABQ": "length_m", "ACB": "nominal_diameter_mm", "ADE": "reference"}
REFERENCE_PREFIX = "clock reference: "
FILE_HEADER = {"A1": "ISO-8859-1", "A2": "en", "A3": ";", "A4": ".", "A5": '"', "A6": "2010"}


# C0 and C1 control characters, the Unicode line and paragraph separators -> space.
_LINE_SAFE = str.maketrans({c: " " for c in [*range(0x20), *range(0x7F, 0xA0), 0x2028, 0x2029]})
_LINE_BREAK = re.compile(r"\r\n|\r|\n")


def field_text(value: str) -> str:
    """``value`` as a field may hold it: control characters and line separators become
    spaces (see the module docstring)."""
    return value.translate(_LINE_SAFE)


def _line(values: Sequence[str], sep: str, quote: str) -> str:
    """One line of fields: cleaned by :func:`field_text`, quoted when they hold ``sep``
    or ``quote`` or begin with ``#`` (quotes doubled)."""
    cells = []
    for value in values:
        value = field_text(value)
        if sep in value or quote in value or value.lstrip().startswith("#"):
            value = quote + value.replace(quote, quote * 2) + quote
        cells.append(value)
    return sep.join(cells)


def _num(value: float | int | None, decimal: str) -> str:
    if value is None:
        return ""
    text = f"{value:.2f}" if isinstance(value, float) else str(value)
    return text.replace(".", decimal)


def _header(survey: Survey, dec: str) -> dict[str, str]:
    """The inspection header codes and values: the fixed ones, and those the survey
    states (a code whose value is not stated is left out)."""
    direction = DIRECTIONS[survey.direction][0] if survey.direction else ""
    node1, node2 = survey.start_node, survey.finish_node
    if direction == "A":
        node1, node2 = node2, node1
    optional = {"AAB": survey.start_node, "AAD": node1, "AAF": node2,
                "AAJ": survey.location, "AAK": direction, "ABC": survey.reference_point,
                "ABH": survey.operator,
                "ACA": SHAPES[survey.shape][0] if survey.shape else "",
                "ACD": MATERIALS[survey.material].en if survey.material else ""}
    # The three node codes go together: one stated node is written with the others empty.
    nodes = bool(survey.start_node or survey.finish_node)
    header = {"AAA": survey.pipe_ref, "ABA": survey.standard, "ABF": survey.date,
              "ABG": survey.time, "ABQ": _num(float(survey.length_m), dec),
              "ACB": str(survey.nominal_diameter_mm), "ACC": str(survey.nominal_diameter_mm),
              "ADE": REFERENCE_PREFIX + survey.reference}
    header.update({code: value for code, value in optional.items()
                   if value or (nodes and code in ("AAB", "AAD", "AAF"))})
    return {code: header[code] for code in sorted(header)}


def write_en13508(surveys: Sequence[tuple[Survey, Sequence[Observation]]]) -> str:
    """The exchange file text for one or more inspections (ISO-8859-1 safe when the
    remarks are).

    The records are written as given: :func:`~pipestitch.standards.observations.with_nodes`
    adds the BCD/BCE node observations an inspection opens and closes with.
    """
    sep, dec, quote = FILE_HEADER["A3"], FILE_HEADER["A4"], FILE_HEADER["A5"]
    lines = [f"#{k}={v}" for k, v in FILE_HEADER.items()]
    for survey, observations in surveys:
        header = _header(survey, dec)
        lines += ["#B01=" + sep.join(header), _line(list(header.values()), sep, quote)]
        lines.append("#C=" + sep.join(OBS_FIELDS))
        for o in observations:
            row = []
            for name in OBS_FIELDS.values():
                value = getattr(o, name)
                row.append(_num(value, dec) if name != "remark" and isinstance(value, float | int)
                           else ("" if value is None else str(value)))
            lines.append(_line(row, sep, quote))
        lines.append("#Z")
    return "\n".join(lines) + "\n"


def _split(line: str, sep: str, quote: str) -> list[str]:
    try:
        return next(csv.reader([line], delimiter=sep, quotechar=quote or None,
                               quoting=csv.QUOTE_MINIMAL if quote else csv.QUOTE_NONE))
    except (csv.Error, TypeError) as exc:   # e.g. a declared separator of two characters
        raise ValueError(f"cannot split with separator {sep!r}, quote {quote!r}: {exc}") from None


def _survey(header: dict[str, str], dec: str) -> Survey:
    ref = header.get("ADE", "")
    length = header.get("ABQ", "").replace(dec, ".")
    try:
        length_m = float(length) if length else float("nan")
        diameter = parse_int(header.get("ACB", ""), "ACB") or 0
    except ValueError as exc:
        raise ValueError(f"inspection header: {exc}") from None
    return Survey(header.get("AAA", ""), header.get("ABF", ""), header.get("ABG", ""), length_m,
                  diameter, ref[len(REFERENCE_PREFIX):] if ref.startswith(REFERENCE_PREFIX) else "",
                  header.get("ABA", ""), **_described(header))


def _name(table: dict, code: str, pick: object) -> str:
    """The name whose code (``pick(entry)``) is ``code``; "" when none is."""
    return next((name for name, entry in table.items() if pick(entry) == code), "")


def _described(header: dict[str, str]) -> dict[str, str]:
    """Survey fields from the optional header codes (codes without a name are dropped)."""
    direction = _name(DIRECTIONS, header.get("AAK", "").strip(), lambda e: e[0])
    node1, node2 = header.get("AAD", ""), header.get("AAF", "")
    start, finish = (node2, node1) if header.get("AAK", "").strip() == "A" else (node1, node2)
    return {"start_node": header.get("AAB", start), "finish_node": finish,
            "direction": direction, "reference_point": header.get("ABC", "").strip(),
            "shape": _name(SHAPES, header.get("ACA", "").strip(), lambda e: e[0]),
            "material": _name(MATERIALS, header.get("ACD", "").strip(), lambda e: e.en),
            "operator": header.get("ABH", ""), "location": header.get("AAJ", "")}


def _observation(letters: list[str], cells: list[str], dec: str) -> Observation:
    values = {OBS_FIELDS[k]: v for k, v in zip(letters, cells, strict=True) if k in OBS_FIELDS}
    for name in ("distance_m", "quant1", "quant2"):
        values[name] = values.get(name, "").replace(dec, ".")
    try:
        distance = float(values.get("distance_m") or "nan")
    except ValueError:
        raise ValueError(f"distance (I) = {values.get('distance_m')!r} is not a number") from None
    return Observation(distance, values.get("code", "").strip(), values.get("char1", "").strip(),
                       values.get("char2", "").strip(), parse_int(values["quant1"], "D"),
                       parse_int(values["quant2"], "E"), values.get("remark", ""),
                       parse_int(values.get("clock_from", ""), "G"),
                       parse_int(values.get("clock_to", ""), "H"),
                       values.get("continuous", "").strip(), values.get("ref", ""))


def parse_en13508(text: str) -> list[tuple[Survey, list[Observation]]]:
    """Parse an exchange file; ValueError names the line and the problem."""
    meta = dict(FILE_HEADER)
    out: list[tuple[Survey, list[Observation]]] = []
    header: dict[str, str] = {}
    letters: list[str] | None = None
    pending: str | None = None          # "B" after a #B line, expecting its values
    observations: list[Observation] = []
    for lineno, line in enumerate(_LINE_BREAK.split(text), start=1):
        if not line.strip():
            continue
        try:
            if line.startswith("#A") and "=" in line:
                key, value = line[1:].split("=", 1)
                meta[key] = value
            elif line.startswith("#B"):
                if "=" not in line:
                    raise ValueError(f"header code line without '=': {line[:40]!r}")
                codes, pending = line.split("=", 1)[1], "B"
                header_codes = _split(codes, meta["A3"], meta["A5"])
            elif pending == "B":
                cells = _split(line, meta["A3"], meta["A5"])
                if len(cells) != len(header_codes):
                    raise ValueError(f"{len(cells)} values for {len(header_codes)} header codes")
                header.update(zip(header_codes, cells, strict=True))
                pending = None
            elif line.startswith("#C="):
                letters = _split(line[3:], meta["A3"], meta["A5"])
                if "I" not in letters or "A" not in letters:
                    raise ValueError("observation block without distance (I) or main code (A)")
            elif line.startswith("#Z"):
                out.append((_survey(header, meta["A4"]), observations))
                header, letters, observations = {}, None, []
            elif letters is not None:
                cells = _split(line, meta["A3"], meta["A5"])
                if len(cells) != len(letters):
                    raise ValueError(f"{len(cells)} fields for {len(letters)} field letters")
                observations.append(_observation(letters, cells, meta["A4"]))
            else:
                raise ValueError(f"unexpected line {line[:40]!r}")
        except ValueError as exc:
            raise ValueError(f"line {lineno}: {exc}") from None
    if letters is not None or header:
        raise ValueError("last inspection block is not closed by #Z")
    return out
