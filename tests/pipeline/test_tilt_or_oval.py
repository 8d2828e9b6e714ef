"""Tilted probe or oval pipe, told by the LED frames where the rings cannot: a run without
a declared probe body, or with one small enough to hold the circle poses."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.io.dataset import open_dataset
from pipestitch.pipeline.posing import estimate_poses
from pipestitch.pipeline.ring_store import RingStore
from pipestitch.pipeline.tilt_or_oval import tilt_or_oval

runner = CliRunner()
POSE = ("alpha_deg", "beta_deg", "dx_mm", "dy_mm")


def _without_body(root: Path, body: str = "") -> Path:
    toml = root / "probe.toml"
    text = re.sub(r"\[probe\]\n(?:[a-z_]+ = [^\n]*\n)*", body, toml.read_text())
    assert ("[probe]" in text) == bool(body)
    toml.write_text(text)
    return root


SMALL_BODY = "[probe]\nlength_mm = 60.0\ndiameter_mm = 20.0\n"   # holds an 18 deg tilt


@pytest.fixture(scope="module", params=["", SMALL_BODY], ids=["no body", "small body"])
def oval(request, tmp_path_factory: pytest.TempPathFactory, simulate_small) -> Path:
    """A 5 % oval pipe (read as a round one, ~18 deg of tilt) that no body rules out."""
    return _without_body(simulate_small(tmp_path_factory.mktemp("oval") / "ds", "--scenario",
                                        "oval", "--pairs", "8"), request.param)


@pytest.fixture(scope="module")
def round_pipe(tmp_path_factory: pytest.TempPathFactory, simulate_small) -> Path:
    return _without_body(simulate_small(tmp_path_factory.mktemp("round") / "ds", "--pairs", "8",
                                        "--seed", "3"))


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


def _errors(out: Path, dataset: Path) -> np.ndarray:
    est, truth = _rows(out / "poses.csv"), _rows(dataset / "truth" / "poses.csv")
    return np.array([[float(e[k]) - float(t[k]) for k in POSE] for e, t in zip(est, truth,
                                                                                strict=True)])


def test_the_led_frames_tell_an_oval_pipe_from_a_tilted_probe(oval: Path) -> None:
    dataset = open_dataset(oval)
    with RingStore() as rings:
        frames, _ = estimate_poses(dataset, show_progress=False, rings=rings)
        found = tilt_or_oval(dataset, frames, dataset.config.camera_model())
    assert found is not None and found.oval and found.share == 0.0
    # the misfit grows with the share of the circle's tilt taken: that tilt is ovality
    assert found.misfits[-1] > 2 * found.misfits[0]


def test_run_measures_an_oval_pipe_without_a_body(oval: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["run", str(oval), "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "the pipe is taken as oval" in result.output
    errors = _errors(tmp_path, oval)
    assert np.max(np.abs(errors[:, :2])) < 0.3      # deg (the circle read: ~18)
    assert np.max(np.abs(errors[:, 2:])) < 0.2      # mm
    rows = _rows(tmp_path / "poses.csv")
    assert all(r["model"] == "oval/refined-tilt" and abs(float(r["ovality"]) - 0.05) < 0.005
               and r["warning"] == "" for r in rows)


def test_pose_flags_the_circle_tilts_of_an_oval_pipe_without_a_body(oval: Path,
                                                                     tmp_path: Path) -> None:
    result = runner.invoke(app, ["pose", str(oval), "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "the pipe looks oval" in result.output
    assert all("ovality" in r["warning"] for r in _rows(tmp_path / "poses.csv"))


def test_a_round_pipe_without_a_body_keeps_its_tilt(round_pipe: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["run", str(round_pipe), "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "taken as oval" not in result.output
    errors = _errors(tmp_path, round_pipe)
    assert np.max(np.abs(errors[:, :2])) < 0.3
    assert np.max(np.abs(errors[:, 2:])) < 0.2
    # no ovality read into a round pipe
    ovality = [float(r["ovality"]) for r in _rows(tmp_path / "poses.csv")]
    assert np.nanmax(ovality) < 0.002


@pytest.fixture(scope="module")
def mild_oval(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 0.6 % oval pipe, 2.5-4.3 deg of true tilt, no body: the ring's circle tilt is
    ~2 deg more, and the LED frames' comparison of no tilt with it cannot tell (both off)."""
    from dataclasses import replace

    from pipestitch.pipeline.simulating import simulate_dataset
    from pipestitch.simulate.scenarios import SCENARIOS

    root = tmp_path_factory.mktemp("mild") / "ds"
    simulate_dataset(replace(SCENARIOS["oval"], ovality=0.006, declare_body=False), root,
                     seed=4, size="half", n_pairs=8, show_progress=False)
    return root


def test_a_mildly_oval_pipe_gets_its_tilt_from_the_led_frames(mild_oval: Path,
                                                              tmp_path: Path) -> None:
    # the refinement's prior leaves what an ovality can mimic to the LED frames
    result = runner.invoke(app, ["run", str(mild_oval), "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    errors = _errors(tmp_path, mild_oval)
    assert np.max(np.abs(errors[:, :2])) < 0.3
    ovality = [float(r["ovality"]) for r in _rows(tmp_path / "poses.csv")]
    assert np.max(np.abs(np.array(ovality) - 0.006)) < 0.002
