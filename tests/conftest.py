"""Shared fixtures: the real third-party data in ../shared/data (skipped when absent)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest

SHARED_DATA = Path(os.environ.get("PIPESTITCH_SHARED_DATA",
                                  Path(__file__).resolve().parents[2] / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Folder of real calibration data and images; skip the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder {SHARED_DATA} not available")
    return SHARED_DATA


def _simulate_small(root: Path, *args: str) -> Path:
    from typer.testing import CliRunner

    from pipestitch.cli.app import app

    result = CliRunner().invoke(app, ["simulate", "--out", str(root), "--size", "half",
                                      "--quiet", *args])
    assert result.exit_code == 0, result.output
    return root


@pytest.fixture(scope="session")
def simulate_small() -> Callable[..., Path]:
    """``simulate_small(root, *cli_args)``: a small half-size dataset made by the real CLI."""
    return _simulate_small
