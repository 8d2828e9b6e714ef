"""Simulator: trajectories respect the probe body, frames agree with the geometry,
datasets follow SPEC."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import BodyEnvelope, PipeSection, Pose, WallGrid, laser_ring
from pipestitch.io.dataset import check_dataset, open_dataset, read_csv_columns
from pipestitch.pipeline.simulating import simulate_dataset
from pipestitch.simulate.render import Optics, Renderer, WallTexture
from pipestitch.simulate.scenarios import SCENARIOS, build_run
from pipestitch.simulate.trajectory import odometer_readings, table1_poses, wandering_poses


@pytest.mark.parametrize("section", [PipeSection.circle(65.0), PipeSection.circle(50.0),
                                     PipeSection.oval(65.0, 0.05, 0.7)])
def test_wandering_poses_keep_the_body_inside(section: PipeSection) -> None:
    body = BodyEnvelope()
    poses = wandering_poses(200, section, body, np.random.default_rng(0), step_mm=5.0)
    clearance = np.array([body.clearance_mm(p, section) for p in poses])
    assert clearance.min() >= 0.3 - 1e-9  # the requested margin
    z = np.array([p.z_mm for p in poses])
    assert 4.0 < np.mean(np.diff(z)) < 6.0 and np.all(np.diff(z) > 0)
    tilt = np.rad2deg([p.tilt for p in poses])
    # The body really wanders (not centred) but slowly: frame-to-frame changes are small.
    assert tilt.max() > 1.0
    assert np.max(np.abs(np.diff(tilt))) < 1.0


def test_table1_poses_follow_the_reference_constraints() -> None:
    r, d = 32.5, 16.0
    poses = table1_poses(500, r, d, np.random.default_rng(1))
    lim = np.arcsin(2 * r / 145)
    a = np.array([[p.alpha, p.beta, p.dx_mm, p.dy_mm] for p in poses])
    assert np.all(np.abs(a[:, :2]) < lim) and np.all(a[:, 2] ** 2 + a[:, 3] ** 2 < r * r)
    centres = np.array([p.to_world(np.array([[0, 0, d]]))[0] for p in poses])
    assert np.all(np.hypot(centres[:, 0], centres[:, 1]) < r)
    assert np.max(np.abs(a[:, 0])) > 0.8 * lim  # the whole range is used


def test_odometer_has_scale_error_and_noise() -> None:
    z = np.linspace(0, 1000, 2001)
    odo = odometer_readings(z, np.random.default_rng(2), scale_error=0.02, noise_mm=0.3)
    slope, intercept = np.polyfit(z, odo, 1)
    # 2001 readings of 0.3 mm noise over 1 m: the slope's standard error is 2.3e-5 and
    # the spread's 1.6 % (measured 2.5e-5 and -1.6 % off), far inside both bounds.
    assert slope == pytest.approx(1.02, abs=1e-3)
    assert np.std(odo - (slope * z + intercept)) == pytest.approx(0.3, rel=0.1)


def _flat_renderer(size: str = "half", optics: Optics | None = None) -> Renderer:
    cam = default_camera(size)
    albedo = np.full((3600, 2000), 0.6, np.float32)
    wall = WallTexture(albedo=albedo, grid=WallGrid(radius_mm=32.5, deg_per_px=0.1,
                                                    mm_per_px_axial=0.1, z0_mm=-50.0,
                                                    n_cols=2000))
    return Renderer(cam, PipeSection.circle(65.0), wall, 16.0, optics)


def test_laser_ring_is_drawn_where_the_geometry_puts_it() -> None:
    renderer = _flat_renderer(optics=Optics(full_well_e=1e9, read_noise=0.0, speckle=0.0))
    pose = Pose.from_degrees(3.0, -2.0, 4.0, -3.0, 0.0, 10.0)
    laser = renderer.render_laser(pose, np.random.default_rng(0)).astype(float)
    cam = renderer.camera
    ring = cam.project(laser_ring(pose, PipeSection.circle(65.0), 16.0, n_points=720))
    visible = renderer.visibility[np.rint(ring[:, 1]).astype(int),
                                  np.rint(ring[:, 0]).astype(int)] > 0.99
    # Along each ring point's radial line the brightest pixel is within 1 px of it.
    centre = cam.project(np.array([[0.0, 0.0, 1.0]]))[0]
    errors = []
    for px in ring[visible][::10]:
        direction = (px - centre) / np.linalg.norm(px - centre)
        t = np.arange(-15, 16)
        samples = np.rint(px + t[:, None] * direction).astype(int)
        values = laser[samples[:, 1], samples[:, 0]]
        errors.append(abs(t[np.argmax(values)]))
    assert np.max(errors) <= 1
    assert laser.max() > 150 and np.median(laser) < 10


def test_arm_and_mirror_are_dark_in_both_frames() -> None:
    renderer = _flat_renderer()
    _, led = renderer.render_pair(Pose(), np.random.default_rng(1))
    cam = renderer.camera
    centre = cam.project(np.array([[0.0, 0.0, 1.0]]))[0]
    # Mirror: the optical axis; arm: straight down (azimuth 90°) at 60° incidence.
    arm = cam.project(np.array([[0.0, np.sin(1.05), np.cos(1.05)]]))[0]
    wall = cam.project(np.array([[np.sin(1.05), 0.0, np.cos(1.05)]]))[0]
    for x, y in (centre, arm):
        assert led[int(round(y)), int(round(x))] < 8
    assert led[int(round(wall[1])), int(round(wall[0]))] > 40


def test_holes_are_dark_where_the_geometry_says() -> None:
    run = build_run(replace(SCENARIOS["test_piece"], optics=Optics(full_well_e=1e9)),
                    seed=3, size="half", n_pairs=20)
    pose = run.poses[10]
    _, led = run.render(10)
    vis = run.renderer.visibility
    hits = 0
    for d in run.defects:
        p_world = run.section.points(np.deg2rad(d.theta_deg), d.z_mm)[None]
        col, row = run.camera.project(pose.to_probe(p_world))[0]
        if not (np.isfinite(col) and 25 <= row < led.shape[0] - 25 and 25 <= col < led.shape[1]
                - 25) or vis[int(row), int(col)] < 1:
            continue
        hits += 1
        patch = led[int(row) - 25:int(row) + 26, int(col) - 25:int(col) + 26]
        # The hole (albedo 0.02) is far darker than the aluminium around it (0.7).
        assert led[int(round(row)), int(round(col))] < 0.3 * np.percentile(patch, 90)
    assert hits >= 3  # most of the 7 holes are in view of the middle frame


def test_dataset_follows_spec(tmp_path: Path) -> None:
    run = simulate_dataset(SCENARIOS["default"], tmp_path / "ds", seed=5, size="half",
                           n_pairs=3, show_progress=False)
    root = tmp_path / "ds"
    assert [p for p in check_dataset(root) if p.severity == "error"] == []
    ds = open_dataset(root)
    assert ds.n_pairs == 3 and ds.has_led and ds.odometry_mm is not None
    poses = read_csv_columns(root / "truth" / "poses.csv",
                             ("frame", "alpha_deg", "beta_deg", "dx_mm", "dy_mm", "z_mm",
                              "roll_deg"))
    np.testing.assert_allclose(poses["alpha_deg"], [np.rad2deg(p.alpha) for p in run.poses],
                               atol=1e-6)
    assert (root / "truth" / "wall.png").is_file() and (root / "truth" / "wall.json").is_file()
    assert ds.read_laser(0).dtype == np.uint8


def test_hard_scenario_writes_16_bit_colour(tmp_path: Path) -> None:
    simulate_dataset(SCENARIOS["hard"], tmp_path, seed=0, size="half", n_pairs=1,
                     show_progress=False)
    img = open_dataset(tmp_path).read_laser(0)
    assert img.dtype == np.uint16 and img.shape == (1024, 1224, 3)


def test_same_seed_same_frames() -> None:
    a = build_run(SCENARIOS["default"], seed=7, size="half", n_pairs=2)
    b = build_run(SCENARIOS["default"], seed=7, size="half", n_pairs=2)
    assert np.array_equal(a.render(1)[1], b.render(1)[1])
    assert a.poses == b.poses


def test_fast_laser_only_rendering_matches_the_pair() -> None:
    run = build_run(SCENARIOS["test_piece"], seed=1, size="half", n_pairs=3)
    for i in range(3):
        alone = run.render_laser(i).astype(int)
        paired = run.render(i)[0].astype(int)
        diff = np.abs(alone - paired)
        # Same seed, same noise: the only difference is the texture filter under the
        # ring (full resolution vs mip-mapped), a few DN on a handful of pixels.
        assert diff.mean() < 0.05 and np.mean(diff > 8) < 1e-4


def test_rendering_in_worker_processes_gives_the_same_frames(tmp_path, simulate_small) -> None:
    """Each pair has its own noise generator: forked workers write the same files."""
    one = simulate_small(tmp_path / "one", "--pairs", "3", "--seed", "5")
    two = simulate_small(tmp_path / "two", "--pairs", "3", "--seed", "5", "--workers", "2")
    names = sorted(p.name for p in (one / "frames").iterdir())
    assert names == sorted(p.name for p in (two / "frames").iterdir()) and len(names) == 6
    for name in names:
        assert (one / "frames" / name).read_bytes() == (two / "frames" / name).read_bytes()


def test_a_texture_off_its_grid_is_refused() -> None:
    grid = WallGrid(radius_mm=32.5, deg_per_px=1.0, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=20)
    WallTexture(albedo=np.zeros((360, 20), np.float32), grid=grid)
    with pytest.raises(ValueError, match="shape"):
        WallTexture(albedo=np.zeros((360, 21), np.float32), grid=grid)


def test_led_frames_taken_as_the_probe_moves_on_along_its_track(tmp_path: Path) -> None:
    """``led_share``: each LED frame at the track's pose that share of the step further
    on (smooth: between the pairs' poses, off their straight line by the track's bend
    only); the laser frames, and a share of 0, as without it."""
    still = build_run(SCENARIOS["corrosion"], seed=3, size="half", n_pairs=6)
    moving = build_run(replace(SCENARIOS["corrosion"], led_share=0.5), seed=3, size="half",
                       n_pairs=6)
    assert still.led_poses is None and moving.poses == still.poses
    assert np.array_equal(moving.render(2)[0], still.render(2)[0])   # the laser frame
    assert not np.array_equal(moving.render(2)[1], still.render(2)[1])
    z = np.array([p.z_mm for p in moving.poses])
    led = moving.led_poses
    assert led is not None
    np.testing.assert_allclose([p.z_mm for p in led[:-1]], 0.5 * (z[:-1] + z[1:]))
    assert led[-1].z_mm == pytest.approx(z[-1] + 0.5 * (z[-1] - z[-2]))
    for i in range(5):
        a, b, m = (np.array([p.alpha, p.beta, p.dx_mm, p.dy_mm])
                   for p in (moving.poses[i], moving.poses[i + 1], led[i]))
        # the midpoint of a smooth track within its bend (<< a step's change), and the
        # steps (3 %) by which a body near the wall is drawn in to clear it
        mid = 0.5 * (a + b)
        assert np.all(np.abs(m - mid) <= 0.1 * np.abs(b - a) + 0.03 * np.abs(mid) + 1e-4)
    written = simulate_dataset(replace(SCENARIOS["corrosion"], led_share=0.5), tmp_path / "ds",
                               seed=3, size="half", n_pairs=2, show_progress=False)
    assert written.led_poses is not None
    truth = read_csv_columns(tmp_path / "ds" / "truth" / "led_poses.csv", ("frame", "z_mm"))
    np.testing.assert_allclose(truth["z_mm"], [p.z_mm for p in written.led_poses], atol=1e-5)
    assert [p for p in check_dataset(tmp_path / "ds") if p.severity == "error"] == []
