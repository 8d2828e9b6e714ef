"""Laser and LED frames swapped (or the pairs shifted by one frame): the ring would be
looked for in the wall's texture and the mosaic made of laser frames. A laser frame is
dark but for its ring, so check, pose and run say so when most laser frames are the
brighter of their pair."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.io.dataset import check_dataset


def _swap(root: Path, pairs: range) -> None:
    frames = root / "frames"
    for i in pairs:
        laser, led = frames / f"laser_{i:05d}.png", frames / f"led_{i:05d}.png"
        shutil.move(laser, frames / "swap.png")
        shutil.move(led, laser)
        shutil.move(frames / "swap.png", led)


def _said(root: Path) -> list[str]:
    return [p.message for p in check_dataset(root) if "swapped" in p.message]


@pytest.fixture()
def dataset(simulate_small, tmp_path: Path) -> Path:
    return simulate_small(tmp_path / "ds", "--scenario", "corrosion", "--pairs", "4")


def test_swapped_frames_are_said_by_check_pose_and_run(dataset: Path, tmp_path: Path) -> None:
    assert _said(dataset) == []
    _swap(dataset, range(4))
    said = _said(dataset)
    assert len(said) == 1 and "twice as bright as their LED frames in 4 of 4 pairs" in said[0]
    for command in ("pose", "run"):
        out = tmp_path / command
        result = CliRunner().invoke(app, [command, str(dataset), "--out", str(out)])
        said = "frames/: the laser frames are over twice as bright as their LED frames in 4 of 4"
        assert said in result.output, result.output
    assert "swapped" in (tmp_path / "run" / "problems.csv").read_text()


def test_one_swapped_pair_of_four_is_not_a_swapped_dataset(dataset: Path) -> None:
    # a lone pair is what a dark LED frame or a glint can make: left to the frame's own
    # messages, not said of the run
    _swap(dataset, range(1))
    assert _said(dataset) == []


def test_laser_frames_lit_as_brightly_as_the_led_frames_are_not_swapped(dataset: Path) -> None:
    """The LEDs (or daylight) on in the laser frames too: each laser frame is its LED
    frame plus the ring, the brighter of the pair, and still the laser frame."""
    frames = dataset / "frames"
    for laser in sorted(frames.glob("laser_*.png")):
        led = cv2.imread(str(frames / laser.name.replace("laser", "led")), cv2.IMREAD_UNCHANGED)
        ring = cv2.imread(str(laser), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(laser), np.clip(ring.astype(np.float32) + led, 0, 255).astype(np.uint8))
    assert _said(dataset) == []

