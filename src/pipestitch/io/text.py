"""Reading small text files (configuration, calibration) with errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path

from pipestitch.errors import ConfigError

__all__ = ["parse_json_object", "read_config_text"]


def read_config_text(path: str | Path) -> str:
    """UTF-8 text of ``path``, a leading byte-order mark (Notepad's UTF-8) left out;
    :class:`ConfigError` naming the file if missing, unreadable or not UTF-8."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8-sig", errors="strict")
    except FileNotFoundError as exc:
        raise ConfigError(path, "file not found") from exc
    except (UnicodeDecodeError, OSError) as exc:
        raise ConfigError(path, f"cannot read as text: {exc}") from exc


def parse_json_object(text: str, path: Path, expected: str) -> dict:
    """A JSON object from ``text``; ConfigError naming ``path`` otherwise.

    ``expected`` says what the object should be, for the message.
    """
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(path, f"malformed JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(path, f"expected a JSON object ({expected})")
    return data
