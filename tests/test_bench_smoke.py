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


def test_first_run_benchmark_saves_frames_again_with_the_same_pixels(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """bench/first_run.py --frames: Pillow's PNGs (a filter chosen for each row), BGR and
    16-bit frames, each decoding to the frame written (colour: the grey value in every
    channel; 16-bit: times 257); an unknown way is refused."""
    import importlib.util

    import cv2
    import numpy as np

    spec = importlib.util.spec_from_file_location("bench_first_run", BENCH / "first_run.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    rng = np.random.default_rng(3)
    grey = np.clip(rng.normal(120, 40, (64, 80)), 0, 255).astype(np.uint8)
    for how, want in (("opencv", grey), ("pillow", grey),
                      ("colour", np.repeat(grey[..., None], 3, axis=2)),
                      ("16bit", grey.astype(np.uint16) * 257)):
        data = tmp_path / how
        (data / "frames").mkdir(parents=True)
        cv2.imwrite(str(data / "frames" / "led_00000.png"), grey)
        module.rewrite_frames(data, how)
        np.testing.assert_array_equal(
            cv2.imread(str(data / "frames" / "led_00000.png"), cv2.IMREAD_UNCHANGED), want)
    assert (tmp_path / "pillow" / "frames" / "led_00000.png").read_bytes() != (
        tmp_path / "opencv" / "frames" / "led_00000.png").read_bytes()
    with pytest.raises(ValueError, match="--frames"):
        module.rewrite_frames(tmp_path / "opencv", "jpeg")
