"""JSON-safe values: non-finite floats (NaN, inf) become null, recursively."""

from __future__ import annotations

import math
from collections.abc import Mapping

__all__ = ["json_safe"]


def json_safe(value: object) -> object:
    """``value`` with every non-finite float inside mappings and sequences set to None."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value
