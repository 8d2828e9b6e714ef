"""Smoke runs of every benchmark (the full runs are not part of CI)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow   # each smoke run is a benchmark script as a subprocess

BENCH = Path(__file__).resolve().parents[1] / "bench"


SMOKE = [   # (script, a line its --quick output must hold)
    ("sensitivity.py", "Delta PX"),
    ("render.py", "pairs/s"),
    ("table1.py", "speed: ours"),
    ("mosaic.py", "pairs/s"),
    ("first_run.py", "first run / warm"),
    ("holes.py", "spacing err"),
    ("ovality.py", "ours (refined tilt)"),
    ("scale.py", "speed ratio cluster vs sequential"),
    ("calibration_real.py", "calibration vs published"),
    ("occluders.py", "SSIM - black"),
    ("report.py", "open in Chromium"),
]


def test_every_benchmark_has_a_smoke_run() -> None:
    assert {script for script, _ in SMOKE} == {p.name for p in BENCH.glob("*.py")}


@pytest.mark.parametrize("script,expect", SMOKE)
def test_benchmark_smoke(script: str, expect: str) -> None:
    proc = subprocess.run([sys.executable, str(BENCH / script), "--quick"], capture_output=True,
                          text=True, check=False, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert expect in proc.stdout
