"""Exception types, one per kind of problem.

Each carries enough context (usually a path) for the CLI to print a message that
names the file and what is wrong, and to map it to an exit code (SPEC: 2 = bad input).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["CalibrationError", "ConfigError", "DatasetError", "PipestitchError", "StageError"]


class PipestitchError(Exception):
    """Base class of every error pipestitch raises on purpose."""

    exit_code = 1


class DatasetError(PipestitchError):
    """A dataset (folder, frame, CSV) is missing, unreadable or malformed."""

    exit_code = 2

    def __init__(self, path: str | Path | None, problem: str) -> None:
        self.path = Path(path) if path is not None else None
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path is not None else problem)


class ConfigError(DatasetError):
    """probe.toml or a calibration file is malformed or inconsistent."""


class CalibrationError(PipestitchError):
    """A calibration could not be computed from the given data."""

    exit_code = 2


class StageError(PipestitchError):
    """A processing stage could not produce its output from valid input (exit 1)."""
