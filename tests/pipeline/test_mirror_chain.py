"""Frames whose mirror only registration decided, against each other: decided when the
stretch registers better as chosen than all mirrored (pipeline/run.py _chain_decided),
checked against the simulator's true poses."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import pytest

from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.simulating import simulate_dataset
from pipestitch.simulate.scenarios import SCENARIOS


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def small_tilts(tmp_path_factory) -> tuple[list[dict], list[dict]]:
    """A probe without a declared body, tilted 0.6-2.1 deg: below the pose step's
    photometric comparison, so no frame's mirror is decided before registration."""
    root = tmp_path_factory.mktemp("chain") / "ds"
    scenario = replace(SCENARIOS["aluminium"], wander=0.3, declare_body=False, n_pairs=14)
    simulate_dataset(scenario, root, seed=1, size="half", show_progress=False)
    run_dataset(root, root.parent / "out", show_progress=False)
    return _rows(root.parent / "out" / "poses.csv"), _rows(root / "truth" / "poses.csv")


def test_a_stretch_decided_by_its_chain_is_on_the_true_mirror(small_tilts) -> None:
    ours, truth = small_tilts
    assert not any(r["chosen_by"] in ("photometric", "envelope") for r in ours)
    chain = [(r, t) for r, t in zip(ours, truth, strict=True)
             if r["chosen_by"] == "registration-chain"]
    assert len(chain) >= len(ours) // 2
    for row, true in chain:
        assert row["ambiguous"] == "0"
        error = max(abs(float(row[k]) - float(true[k])) for k in ("alpha_deg", "beta_deg"))
        offset = max(abs(float(row[k]) - float(true[k])) for k in ("dx_mm", "dy_mm"))
        assert error < 0.1 and offset < 0.1, (row["frame"], error, offset)


def test_no_frame_is_left_unflagged_on_its_wrong_mirror(small_tilts) -> None:
    ours, truth = small_tilts
    for row, true in zip(ours, truth, strict=True):
        error = max(abs(float(row[k]) - float(true[k])) for k in ("alpha_deg", "beta_deg"))
        assert row["ambiguous"] == "1" or error < 0.5, row["frame"]
