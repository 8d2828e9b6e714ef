"""PACP condition ratings from condition grades: the ``PACP_Ratings`` table.

A PACP condition carries a structural or an operation-and-maintenance (O&M) grade, 1 to
5, and a number of occurrences (usually 1; more for a long continuous defect). The
ratings of one inspection follow from those alone (docs/standards.md, "PACP_Ratings"):

* grade score of grade g = g x (occurrences of grade g), per type;
* pipe rating = the sum of the grade scores of a type; overall = structural + O&M;
* pipe ratings index = pipe rating / occurrences of that type (overall: all occurrences);
* quick rating = highest grade, its occurrences, second highest grade, its occurrences,
  four characters (``5345``); a missing second grade is written ``00``.

What is not here: the grade of each PACP code (PACP's tables, not public, so pipestitch
assigns no grades: a caller that has graded its conditions passes the grades), the
quick-rating form for more than 9 occurrences of a grade (not checked: the quick rating
is then left empty) and ``LoFPACP`` (likelihood of failure, left empty).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from pipestitch.standards.observations import csv_record, csv_records, parse_int

__all__ = ["GRADES", "RATING_COLUMNS", "ConditionGrade", "PacpRatings", "pacp_ratings",
           "parse_pacp_ratings", "write_pacp_ratings"]

GRADES = (1, 2, 3, 4, 5)
_KINDS = {"ST": "structural", "OM": "om"}
RATING_COLUMNS = ("InspectionID", *(f"{kind}GradeScore{g}" for kind in _KINDS for g in GRADES),
                  "STPipeRating", "OMPipeRating", "OverallPipeRating", "STQuickRating",
                  "OMQuickRating", "PACPQuickRating", "STPipeRatingsIndex",
                  "OMPipeRatingsIndex", "OverallPipeRatingsIndex", "LoFPACP")
Counts = tuple[int, int, int, int, int]


def _check_grade(value: int | None, name: str) -> None:
    if value is not None and value not in GRADES:
        raise ValueError(f"{name} grade: expected 1 to 5, got {value!r}")


@dataclass(frozen=True)
class ConditionGrade:
    """The grades of one condition: structural and/or O&M (1-5, None = not graded) and
    the number of occurrences the condition counts for."""

    structural: int | None = None
    om: int | None = None
    occurrences: int = 1

    def __post_init__(self) -> None:
        _check_grade(self.structural, "structural")
        _check_grade(self.om, "O&M")
        if self.occurrences < 1:
            raise ValueError(f"occurrences: expected >= 1, got {self.occurrences}")


@dataclass(frozen=True)
class PacpRatings:
    """Occurrences per grade (index 0 = grade 1) of each type; every rating derives
    from them."""

    structural: Counts = (0, 0, 0, 0, 0)
    om: Counts = (0, 0, 0, 0, 0)

    def __post_init__(self) -> None:
        for name in _KINDS.values():
            counts = getattr(self, name)
            if len(counts) != len(GRADES) or any(n < 0 for n in counts):
                raise ValueError(f"{name}: expected 5 counts >= 0, got {counts!r}")

    @property
    def overall(self) -> Counts:
        """Occurrences per grade, both types together."""
        return tuple(s + o for s, o in zip(self.structural, self.om, strict=True))

    def scores(self, kind: str) -> tuple[int, ...]:
        """Grade scores (grade x occurrences) of ``kind``: structural, om or overall."""
        return tuple(g * n for g, n in zip(GRADES, getattr(self, kind), strict=True))

    def rating(self, kind: str) -> int:
        """Pipe rating: the sum of the grade scores."""
        return sum(self.scores(kind))

    def index(self, kind: str) -> float | None:
        """Pipe ratings index: the rating per occurrence; None without occurrences."""
        total = sum(getattr(self, kind))
        return self.rating(kind) / total if total else None

    def quick(self, kind: str) -> str:
        """Quick rating: the two highest grades present, each with its occurrences;
        "" when a count is over 9 (the form for that was not checked)."""
        present = [(g, n) for g, n in zip(GRADES, getattr(self, kind), strict=True) if n][::-1]
        if any(n > 9 for _, n in present[:2]):
            return ""
        return "".join(f"{g}{n}" for g, n in present[:2]).ljust(4, "0")


def pacp_ratings(grades: Iterable[ConditionGrade]) -> PacpRatings:
    """The ratings of an inspection whose conditions have ``grades``."""
    counts = {name: [0] * len(GRADES) for name in _KINDS.values()}
    for grade in grades:
        for name in _KINDS.values():
            if getattr(grade, name) is not None:
                counts[name][getattr(grade, name) - 1] += grade.occurrences
    return PacpRatings(tuple(counts["structural"]), tuple(counts["om"]))


def _index_cell(value: float | None) -> str:
    return "" if value is None else f"{value:.2f}"


def write_pacp_ratings(ratings: PacpRatings, inspection_id: int = 1) -> str:
    """The ``PACP_Ratings`` CSV text: a header and one row for the inspection."""
    values = [str(inspection_id)]
    values += [str(s) for name in _KINDS.values() for s in ratings.scores(name)]
    kinds = ("structural", "om", "overall")
    values += [str(ratings.rating(k)) for k in kinds]
    values += [ratings.quick(k) for k in kinds]
    values += [_index_cell(ratings.index(k)) for k in kinds]
    values.append("")                                   # LoFPACP: not computed
    return csv_record(RATING_COLUMNS) + csv_record(values)


def _counts(row: dict[str, str], prefix: str) -> Counts:
    out = []
    for g in GRADES:
        column = f"{prefix}GradeScore{g}"
        score = parse_int(row.get(column, ""), column) or 0
        if score % g:
            raise ValueError(f"{column} = {score}: not a multiple of the grade {g}")
        out.append(score // g)
    return tuple(out)


def parse_pacp_ratings(text: str) -> PacpRatings:
    """Read a ``PACP_Ratings`` table back (its first row) from the grade scores.

    ValueError names the table and the problem, also when a pipe rating written in the
    table disagrees with its grade scores.
    """
    records = csv_records(text)
    _, _, columns = next(records, (1, "", []))
    rows = [dict(zip(columns, cells, strict=False)) for _, _, cells in records if cells]
    if not rows:
        raise ValueError("PACP_Ratings: no row")
    try:
        ratings = PacpRatings(*(_counts(rows[0], prefix) for prefix in _KINDS))
        _check_ratings(rows[0], ratings)
    except ValueError as exc:
        raise ValueError(f"PACP_Ratings: {exc}") from None
    return ratings


def _check_ratings(row: dict[str, str], ratings: PacpRatings) -> None:
    names: Sequence[tuple[str, str]] = (("STPipeRating", "structural"), ("OMPipeRating", "om"),
                                        ("OverallPipeRating", "overall"))
    for column, kind in names:
        written = parse_int(row.get(column, ""), column)
        if written is not None and written != ratings.rating(kind):
            raise ValueError(f"{column} = {written}, the grade scores give "
                             f"{ratings.rating(kind)}")
