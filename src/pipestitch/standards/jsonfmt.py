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


def parse_json(text: str) -> tuple[Survey, list[Observation]]:
    """Read the JSON export back; ValueError says what is wrong."""
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"expected format {FORMAT!r}")
    survey = dict(doc.get("survey") or {})
    if survey.get("length_m") is None:
        survey["length_m"] = math.nan
    names = {f.name for f in fields(Observation)}
    try:
        return (Survey(**survey),
                [Observation(**{k: v for k, v in o.items() if k in names})
                 for o in doc.get("observations", [])])
    except TypeError as exc:
        raise ValueError(f"bad record: {exc}") from None
