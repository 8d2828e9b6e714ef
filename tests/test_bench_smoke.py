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
    ("pose_sigma.py", "run (refined)"),
    ("pair_motion.py", "pose unaware"),
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


def test_mosaic_benchmark_slips_the_odometer_from_mid_run(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """bench/mosaic.py --slip-mm: the odometer reads that much short from the middle
    frame on, every reading before it as written."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_mosaic", BENCH / "mosaic.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)   # its dataclasses look it up
    spec.loader.exec_module(module)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,0.5\n1,5.25\n2,10.0\n3,15.125\n")
    module.slip_odometer(tmp_path, 4.0)
    lines = (tmp_path / "odometry.csv").read_text().splitlines()
    assert lines == ["frame,z_mm", "0,0.500000", "1,5.250000", "2,6.000000", "3,11.125000"]
    with pytest.raises(ValueError, match="no odometer"):
        module.slip_odometer(tmp_path / "missing", 4.0)
