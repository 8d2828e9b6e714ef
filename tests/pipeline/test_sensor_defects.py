"""A sensor with hot pixels and row noise: the hot pixels are found from the LED frames
and repaired before registration, so the refined poses stay near the simulator's truth
(before: a feature-poor wall's tilts up to 1.9 deg off, unflagged)."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipestitch.pipeline.run import run_dataset


def _add_sensor_defects(root: Path, seed: int = 7) -> None:
    """0.1 % of the pixels stuck at full scale and a fixed pattern of row offsets
    (3 DN) plus row noise changing from frame to frame (1.5 DN), in every frame."""
    rng = np.random.default_rng(seed)
    paths = sorted((root / "frames").glob("*.png"))
    shape = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED).shape
    hot = rng.choice(shape[0] * shape[1], shape[0] * shape[1] // 1000, replace=False)
    rows = rng.normal(0.0, 3.0, shape[0])
    for path in paths:
        frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32)
        frame += (rows + rng.normal(0.0, 1.5, shape[0]))[:, None]
        frame.flat[hot] = 255
        cv2.imwrite(str(path), np.clip(frame, 0, 255).astype(np.uint8))


@pytest.fixture(scope="module")
def defective(simulate_small, tmp_path_factory) -> tuple[list[dict], list[dict]]:
    root = simulate_small(tmp_path_factory.mktemp("defects") / "ds", "--scenario",
                          "aluminium", "--pairs", "10", "--seed", "2")
    _add_sensor_defects(root)
    run_dataset(root, root.parent / "out", show_progress=False)
    with (root.parent / "out" / "poses.csv").open(newline="") as f:
        ours = list(csv.DictReader(f))
    with (root / "truth" / "poses.csv").open(newline="") as f:
        truth = list(csv.DictReader(f))
    return ours, truth


def test_hot_pixels_do_not_bend_the_refined_tilts(defective) -> None:
    ours, truth = defective
    errors = [max(abs(float(r[k]) - float(t[k])) for k in ("alpha_deg", "beta_deg"))
              for r, t in zip(ours, truth, strict=True)]
    # the same run without the defects: at most 0.035 deg; the row noise stays
    assert max(errors) < 0.3, errors
