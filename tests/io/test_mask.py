"""The occluder mask file (SPEC ``[probe] mask``): read, validated, written."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from pipestitch.errors import DatasetError
from pipestitch.io.dataset import check_dataset
from pipestitch.io.mask import read_mask, write_mask
from pipestitch.io.probe_toml import read_probe_toml


def _with_mask(root: Path, image: np.ndarray | None, name: str = "mask.png") -> Path:
    with (root / "probe.toml").open("a", encoding="utf-8") as handle:
        handle.write(f'\n[probe]\nmask = "{name}"\n')
    if image is not None:
        cv2.imwrite(str(root / name), image)
    return root


@pytest.fixture()
def dataset(tmp_path: Path, simulate_small) -> Path:
    # the Table-1 scenario declares no [probe] body, so a [probe] section can be added
    return simulate_small(tmp_path / "ds", "--scenario", "table1_65", "--pairs", "2")


def test_mask_round_trip_and_convention(dataset: Path) -> None:
    cfg = read_probe_toml(dataset / "probe.toml")
    occluded = np.zeros((cfg.camera.height, cfg.camera.width), bool)
    occluded[:, :40] = True
    write_mask(dataset / "mask.png", occluded)
    assert set(np.unique(cv2.imread(str(dataset / "mask.png"), cv2.IMREAD_UNCHANGED))) == {0, 255}
    _with_mask(dataset, None)
    np.testing.assert_array_equal(read_mask(dataset, read_probe_toml(dataset / "probe.toml")),
                                  occluded)
    problems = check_dataset(dataset)
    assert not [p for p in problems if p.severity == "error" or p.path.name == "mask.png"]


def test_a_mask_that_hides_the_ring_is_said_to_be_inverted(dataset: Path, tmp_path: Path
                                                           ) -> None:
    """0 where the wall is seen (the convention the other way round): the ring search
    would find nothing, so check and pose (and run, as pose) say so, naming the mask."""
    from typer.testing import CliRunner

    from pipestitch.cli.app import app

    cfg = read_probe_toml(dataset / "probe.toml")
    seen = np.zeros((cfg.camera.height, cfg.camera.width), np.uint8)
    seen[:10, :10] = 255     # the wall "seen" in one corner only
    _with_mask(dataset, seen)
    said = [p for p in check_dataset(dataset) if p.path == dataset / "mask.png"]
    assert [p.severity for p in said] == ["warning"], said
    assert "hides 100% of where the laser ring" in said[0].message
    assert "is it inverted?" in said[0].message
    result = CliRunner().invoke(app, ["pose", str(dataset), "--out", str(tmp_path / "o")])
    # no ring where the mask lets the search look: said, and why
    assert "ring not found" in result.output and "no frame gave a pose" in result.output
    assert "mask.png: the mask hides 100%" in result.output


@pytest.mark.parametrize(("image", "message"), [
    (None, "file not found"),
    (np.full((10, 12), 255, np.uint8), "mask is 12x10"),
    (np.zeros((1, 1, 3), np.uint8), "expected a grey image"),
    ("zeros", "0 everywhere"),
])
def test_bad_masks_are_named(dataset: Path, image, message: str) -> None:
    cfg = read_probe_toml(dataset / "probe.toml")
    if isinstance(image, str):
        image = np.zeros((cfg.camera.height, cfg.camera.width), np.uint8)
    _with_mask(dataset, image)
    cfg = read_probe_toml(dataset / "probe.toml")
    with pytest.raises(DatasetError, match=message) as info:
        read_mask(dataset, cfg)
    assert info.value.path == dataset / "mask.png"
    problems = check_dataset(dataset)
    assert any(p.path == dataset / "mask.png" and message in p.message for p in problems)


def test_a_mask_outside_the_dataset_is_refused(dataset: Path) -> None:
    _with_mask(dataset, None, name="../mask.png")
    with pytest.raises(DatasetError, match="inside the dataset"):
        read_mask(dataset, read_probe_toml(dataset / "probe.toml"))


@pytest.mark.parametrize("command", ["run", "pose"])
@pytest.mark.parametrize("image", [None, np.zeros((10, 10), np.uint8)])
def test_run_and_pose_with_a_bad_mask_exit_2_before_the_work(dataset: Path, tmp_path: Path,
                                                             command: str, image) -> None:
    # a dataset that declares a mask it cannot read is bad input to every command alike
    # (`pose` reads it for the ring search)
    from typer.testing import CliRunner

    from pipestitch.cli.app import app

    _with_mask(dataset, image)
    result = CliRunner().invoke(app, [command, str(dataset), "--out", str(tmp_path / "o"),
                                      "-q"])
    assert result.exit_code == 2 and "mask.png" in result.output, result.output
    assert not (tmp_path / "o" / "poses.csv").exists()
