"""JSON export: the survey header, the observations and (optionally) the named
ovality figures per section, as one document."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, fields

from pipestitch.jsonsafe import json_safe
from pipestitch.standards.observations import Observation, Survey

__all__ = ["parse_json", "write_json_text"]

FORMAT = "pipestitch-observations/1"


def write_json_text(survey: Survey, observations: Sequence[Observation],
                    extra: Mapping[str, object] | None = None) -> str:
    """JSON text; NaN becomes null. ``extra`` (e.g. the ovality definitions and
    figures) is stored under its own keys and ignored by :func:`parse_json`."""
    doc = {"format": FORMAT, "survey": asdict(survey),
           "observations": [asdict(o) for o in observations], **(extra or {})}
    return json.dumps(json_safe(doc), indent=2, ensure_ascii=False) + "\n"


def _checked(record: object, cls: type, what: str) -> dict[str, object]:
    """``record``'s fields of ``cls`` with the types the dataclass declares (an int where
    a float is declared is fine; booleans are not numbers); ValueError otherwise."""
    if not isinstance(record, dict):
        raise ValueError(f"{what}: expected an object, got {type(record).__name__}")
    out = {}
    for f in fields(cls):
        if f.name not in record:
            continue
        value, kinds = record[f.name], _KINDS.get(str(f.type), (object,))
        if isinstance(value, bool) or not isinstance(value, kinds):
            raise ValueError(f"{what}: {f.name} = {value!r} is not {str(f.type)!r}")
        out[f.name] = value
    return out


_KINDS: dict[str, tuple[type, ...]] = {
    "str": (str,), "float": (int, float), "int": (int,), "int | None": (int, type(None)),
}


def parse_json(text: str) -> tuple[Survey, list[Observation]]:
    """Read the JSON export back; ValueError says what is wrong."""
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"expected format {FORMAT!r}")
    survey = doc.get("survey") or {}
    if isinstance(survey, dict) and survey.get("length_m") is None:
        survey = {**survey, "length_m": math.nan}        # NaN is written as null
    survey = _checked(survey, Survey, "survey")
    records = doc.get("observations", [])
    if not isinstance(records, list):
        raise ValueError("observations: expected a list")
    try:
        return (Survey(**survey),   # type: ignore[arg-type]
                [Observation(**_checked(o, Observation, f"observation {k}"))  # type: ignore[arg-type]
                 for k, o in enumerate(records, start=1)])
    except TypeError as exc:
        raise ValueError(f"bad record: {exc}") from None
