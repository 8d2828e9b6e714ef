"""A reflection of the laser ring (a second ring as strong as the ring, at another image
radius) does not take the pose: the ring nearer the nominal pipe is kept, and said. Nor
does a glow far brighter than the ring: a point probe (no body declared) whose mirror
mount glows in the laser frames, a bright circle about the optical axis well inside
the ring. With probe.toml's mask the glow is never a candidate; without it, the ring
search keeps the ring's fainter maxima, and the second-ring check finds the ring there
and keeps it as the one nearer the nominal pipe."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.camera import pixel_grid
from pipestitch.cli.app import app
from pipestitch.io.dataset import open_dataset
from pipestitch.simulate.optics import Optics

GHOST_SCALE = 0.92          # image radius of the reflection against the ring's


def _add_ghosts(root: Path, scale: float = GHOST_SCALE, level: float = 1.0) -> None:
    """Every laser frame plus a copy of itself scaled about the image of the optical
    axis (and moved a few pixels), ``level`` times as bright: a second ring, inside the
    first when ``scale`` < 1."""
    centre = open_dataset(root).config.camera_model().project(np.array([[0.0, 0.0, 1.0]]))[0]
    for path in sorted((root / "frames").glob("laser_*.png")):
        frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32)
        warp = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), 0, scale)
        warp[:, 2] += (6.0, -4.0)
        ghost = cv2.warpAffine(frame, warp, (frame.shape[1], frame.shape[0]))
        cv2.imwrite(str(path), np.clip(frame + level * ghost, 0, 255).astype(np.uint8))


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def ghost_poses(simulate_small, tmp_path_factory) -> tuple[list[dict], list[dict]]:
    root = simulate_small(tmp_path_factory.mktemp("ghost") / "ds", "--scenario", "corrosion",
                          "--pairs", "6", "--seed", "0")
    _add_ghosts(root)
    out = root.parent / "out"
    result = CliRunner().invoke(app, ["pose", str(root), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    return _rows(out / "poses.csv"), _rows(root / "truth" / "poses.csv")


def _assert_the_ring_gives_the_pose(ours: list[dict], truth: list[dict]) -> None:
    assert len(ours) == len(truth)
    for row, true in zip(ours, truth, strict=True):
        assert abs(float(row["radius_mm"]) - 32.5) < 0.05, row
        # up to the mirror (the second ring does not decide it): either hypothesis
        errors = [max(abs(float(row[p + k]) - float(true[k])) for k in ("alpha_deg", "beta_deg"))
                  for p in ("", "alt_")]
        assert min(errors) < 0.5, (row["frame"], errors)


def test_the_ring_not_its_reflection_gives_the_pose(ghost_poses) -> None:
    _assert_the_ring_gives_the_pose(*ghost_poses)


def test_a_frame_with_two_rings_says_so(ghost_poses) -> None:
    ours, _ = ghost_poses
    for row in ours:
        assert "two rings in the laser frame" in row["warning"], row
        other = float(row["warning"].split("radius ")[1].split(" and ")[1].split(" mm")[0])
        assert 24.0 < other < 29.0     # the reflection's radius is named


def test_a_faint_reflection_nearer_a_wrong_nominal_does_not_take_the_pose(
        simulate_small, tmp_path: Path) -> None:
    """A reflection outside the ring (~41.8 mm on the wall) at 0.15 of its brightness,
    under the ring search's relative floor, and probe.toml's nominal 80 mm pipe for the
    65 mm one: the reflection is nearer the nominal, but the ring fitted at a possible
    size (half to twice the nominal) is not displaced by maxima that faint."""
    root = simulate_small(tmp_path / "ds", "--scenario", "corrosion", "--pairs", "4",
                          "--seed", "2")
    _add_ghosts(root, scale=1.08, level=0.15)
    toml = root / "probe.toml"
    toml.write_text(toml.read_text().replace("inner_diameter_mm = 65.0",
                                             "inner_diameter_mm = 80.0"))
    for row in _pose(root):
        assert abs(float(row["radius_mm"]) - 32.5) < 0.05, row
        assert "two rings" not in row["warning"]


# --- a glow far brighter than the ring ----------------------------------------------

PLANE_MM = 16.0            # the simulated probe's laser plane (probe.toml)
GLOW_LEVEL = 0.9           # the glow's peak, fraction of full scale (the ring's is 0.8)


def _incidence_deg(root: Path) -> np.ndarray:
    """Angle of each pixel's ray from the optical axis (NaN off the lens)."""
    camera = open_dataset(root).config.camera_model()
    rays = camera.unproject(pixel_grid(camera.width, camera.height).reshape(-1, 2))
    return np.degrees(np.arccos(np.clip(rays[:, 2], -1, 1))).reshape(camera.height,
                                                                     camera.width)


def _point_probe_with_glowing_mount(root: Path, ring: bool = True) -> None:
    """Drop the probe body from probe.toml (the search then starts at the image centre)
    and add the mount's glow to every laser frame (to a black one without the ``ring``):
    a thin circle 1 deg inside the edge the simulator gives the mirror assembly
    (Optics.mirror_radius_mm at the plane)."""
    toml = root / "probe.toml"
    text = toml.read_text()
    text = text.replace("length_mm = 145.0\n", "").replace("diameter_mm = 45.0\n", "")
    toml.write_text(text)
    mount_deg = np.degrees(np.arctan2(Optics().mirror_radius_mm, PLANE_MM))
    glow = GLOW_LEVEL * 255 * np.exp(-0.5 * ((_incidence_deg(root) - (mount_deg - 1.0)) / 0.3)**2)
    glow = np.nan_to_num(glow)
    for path in sorted((root / "frames").glob("laser_*.png")):
        frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32) * ring
        cv2.imwrite(str(path), np.clip(frame + glow, 0, 255).astype(np.uint8))


def _declare_mask(root: Path) -> None:
    """probe.toml names a mask that hides the mirror assembly (out to 1 deg past its
    edge) and what lies off the lens."""
    incidence = _incidence_deg(root)
    mount_deg = np.degrees(np.arctan2(Optics().mirror_radius_mm, PLANE_MM))
    hidden = ~np.isfinite(incidence) | (incidence < mount_deg + 1.0)
    cv2.imwrite(str(root / "mask.png"), np.where(hidden, 0, 255).astype(np.uint8))
    toml = root / "probe.toml"
    toml.write_text(toml.read_text().replace("[probe]\n", '[probe]\nmask = "mask.png"\n'))


@pytest.fixture(scope="module")
def glowing(simulate_small, tmp_path_factory) -> Path:
    root = simulate_small(tmp_path_factory.mktemp("glow") / "ds", "--scenario", "corrosion",
                          "--pairs", "6", "--seed", "1")
    _point_probe_with_glowing_mount(root)
    return root


def _pose(root: Path) -> list[dict[str, str]]:
    out = root.parent / f"out_{root.name}"
    result = CliRunner().invoke(app, ["pose", str(root), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    return _rows(out / "poses.csv")


def test_without_a_mask_the_ring_fainter_than_the_glow_is_found_and_kept(glowing) -> None:
    ours = _pose(glowing)
    _assert_the_ring_gives_the_pose(ours, _rows(glowing / "truth" / "poses.csv"))
    for row in ours:
        assert "two rings in the laser frame" in row["warning"], row
        other = float(row["warning"].split("radius ")[1].split(" and ")[1].split(" mm")[0])
        assert other < 10.0     # the glow's radius on the wall is named


def test_with_the_mask_declared_the_glow_is_never_a_candidate(glowing, tmp_path) -> None:
    root = tmp_path / "masked"
    shutil.copytree(glowing, root)
    _declare_mask(root)
    ours = _pose(root)
    _assert_the_ring_gives_the_pose(ours, _rows(root / "truth" / "poses.csv"))
    assert not any("two rings" in row["warning"] for row in ours)


def test_the_glow_alone_gives_no_pose_and_says_why(simulate_small, tmp_path: Path) -> None:
    """The laser ring hidden (black laser frames but for the glow): the only ring is that
    of a ~5.7 mm pipe in a 65 mm one, not the wall's; no frame gets a pose from it."""
    root = simulate_small(tmp_path / "ds", "--scenario", "corrosion", "--pairs", "3",
                          "--seed", "3")
    _point_probe_with_glowing_mount(root, ring=False)
    result = CliRunner().invoke(app, ["pose", str(root), "--out", str(tmp_path / "o")])
    assert "no frame gave a pose" in result.output, result.output
    for row in _rows(tmp_path / "o" / "poses.csv"):
        assert row["error"].startswith("the ring found is that of a pipe of radius "), row
        assert float(row["error"].split("radius ")[1].split(" mm")[0]) < 10.0
        assert "not between half and twice the nominal 32.50 mm" in row["error"]

