"""Unwrapping a frame onto the wall grid: against the simulator's true wall, the exact
projection and the polar baseline.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.camera.frames import to_grey
from pipestitch.geometry import PipeSection, Pose, RadiusProfile, WallGrid
from pipestitch.mosaic.unwrap import (
    default_mm_per_px,
    pack_mask,
    polar_unwrap_maps,
    strip_window_mm,
    unwrap_maps,
    unwrap_with_quality,
)
from pipestitch.simulate.evaluate import WallImage, score_mosaic
from pipestitch.simulate.render import Optics, Renderer, WallTexture
from pipestitch.simulate.textures import make_wall

R = 32.5


CAMERA = default_camera("half")


@pytest.fixture(scope="module")
def wall() -> tuple[WallGrid, np.ndarray]:
    grid = WallGrid.square(R, 0.07, -40.0, 160.0)
    return grid, make_wall("chart", grid, rng=np.random.default_rng(3))


@pytest.fixture(scope="module")
def renderer(wall: tuple[WallGrid, np.ndarray]) -> Renderer:
    grid, albedo = wall
    texture = WallTexture(albedo=albedo, grid=grid)
    return Renderer(CAMERA, PipeSection.circle(2 * R), texture, 16.0, Optics())


def _truth(wall: tuple[WallGrid, np.ndarray]) -> WallImage:
    grid, albedo = wall
    return WallImage(image=albedo, grid=grid)


def _strip_score(renderer: Renderer, wall: tuple[WallGrid, np.ndarray], true_pose: Pose,
                 used_pose: Pose) -> tuple[float, float]:
    """SSIM and geometric RMS of one LED frame unwrapped with ``used_pose``."""
    _, led = renderer.render_pair(true_pose, np.random.default_rng(0))
    mm = default_mm_per_px(CAMERA, R)
    grid = WallGrid.window(R, mm, 0.0, 30.0)
    maps = unwrap_maps(CAMERA, used_pose, PipeSection(R), grid, step=4, with_quality=True)
    strip = unwrap_with_quality(to_grey(led), maps)
    image = np.where(strip.weight > 0, strip.values / strip.shading, np.nan)
    s = score_mosaic(WallImage(image=image, grid=grid), _truth(wall), true_pose.z_mm,
                     np.rad2deg(true_pose.roll))
    return s.ssim, s.geometric_rms_mm


def test_centred_frame_unwraps_to_the_true_wall(renderer: Renderer, wall) -> None:
    pose = Pose.from_degrees(0, 0, 0, 0, 10.0, 40.0)
    ssim, rms = _strip_score(renderer, wall, pose, pose)
    assert ssim > 0.85 and rms < 0.05


def test_offset_tilted_frame_needs_its_pose(renderer: Renderer, wall) -> None:
    pose = Pose.from_degrees(3.0, -2.0, 4.0, -3.0, 10.0, 40.0)
    ssim, rms = _strip_score(renderer, wall, pose, pose)
    ssim_c, rms_c = _strip_score(renderer, wall, pose, Pose(z_mm=40.0, roll=pose.roll))
    # The wall 7 mm further on one side is seen more coarsely than in the centred case,
    # so the bound is the mosaic target (SSIM 0.8), not the centred frame's.
    assert ssim > 0.8 and rms < 0.05
    assert rms_c > 5 * rms and ssim_c < ssim - 0.2


def test_a_reducer_in_the_strip_unwraps_onto_the_wall_the_profile_gives(wall) -> None:
    # The wall narrows 6 % between z 50 and 70 mm: the frame at z 40 sees it 10-30 mm
    # ahead. Unwrapped onto its ring's section alone, that part of the strip is
    # stretched; onto the profile (in the frame's own z), it lies where the wall is.
    grid, albedo = wall
    reducer = RadiusProfile(np.array([50.0, 70.0]), np.array([1.0, 0.94]))
    narrowing = Renderer(CAMERA, PipeSection.circle(2 * R),
                         WallTexture(albedo=albedo, grid=grid), 16.0, Optics(), profile=reducer)
    pose = Pose.from_degrees(2.0, -1.0, 3.0, -2.0, 10.0, 40.0)
    _, led = narrowing.render_pair(pose, np.random.default_rng(0))
    strip_grid = WallGrid.window(R, default_mm_per_px(CAMERA, R), 5.0, 30.0)
    scores = []
    for profile in (reducer.shifted(pose.z_mm), None):
        maps = unwrap_maps(CAMERA, pose, PipeSection(R), strip_grid, step=4, with_quality=True,
                           profile=profile)
        strip = unwrap_with_quality(to_grey(led), maps)
        image = np.where(strip.weight > 0, strip.values / strip.shading, np.nan)
        scores.append(score_mosaic(WallImage(image=image, grid=strip_grid), _truth(wall),
                                   pose.z_mm, np.rad2deg(pose.roll)))
    onto_wall, onto_section = scores
    assert onto_wall.geometric_rms_mm < 0.05 and onto_wall.ssim > 0.8
    assert onto_section.geometric_rms_mm > 5 * onto_wall.geometric_rms_mm


def test_coarse_maps_match_exact_projection() -> None:
    grid = WallGrid.window(R, 0.135, -13.0, 50.0)
    pose = Pose.from_degrees(3, -2, 4, -3)
    mx, my = unwrap_maps(CAMERA, pose, PipeSection(R), grid)
    fast = unwrap_maps(CAMERA, pose, PipeSection(R), grid, step=4, with_quality=True)
    ok = (mx >= 0) & (fast.map_x >= 0) & (fast.quality > 0.5)
    assert ok.mean() > 0.3
    assert np.max(np.hypot(mx - fast.map_x, my - fast.map_y)[ok]) < 0.05
    assert np.mean((mx >= 0) != (fast.map_x >= 0)) < 1e-3   # same visible region


def test_quality_falls_with_distance_and_shading_with_offset() -> None:
    grid = WallGrid.window(R, 0.135, 0.0, 60.0)
    m = unwrap_maps(CAMERA, Pose.from_degrees(0, 0, 5.0, 0), PipeSection(R), grid, step=4,
                    with_quality=True)
    q = m.quality.mean(axis=0)
    assert q[10] > 2 * q[-10] > 0
    near = round(0 / grid.deg_per_px)          # theta 0: the wall 5 mm closer
    far = round(180 / grid.deg_per_px)
    assert m.shading[near, 50] > 1.3 * m.shading[far, 50]


def test_polar_baseline_equals_centred_unwrap_for_a_centred_principal_point() -> None:
    cam = dataclasses.replace(CAMERA, center_col=(CAMERA.width - 1) / 2,
                              center_row=(CAMERA.height - 1) / 2, c=1.0, d=0.0, e=0.0)
    grid = WallGrid.window(R, 0.2, 5.0, 40.0)
    ours = unwrap_maps(cam, Pose(), PipeSection(R), grid)
    polar = polar_unwrap_maps(cam, R, grid)
    assert np.max(np.abs(ours[0] - polar.map_x)) < 1e-3
    assert np.max(np.abs(ours[1] - polar.map_y)) < 1e-3


def test_default_scale_and_window() -> None:
    mm = default_mm_per_px(CAMERA, R)
    assert 0.1 < mm < 0.2
    assert default_mm_per_px(default_camera("full"), R) == pytest.approx(mm / 2, rel=0.02)
    z0, z1 = strip_window_mm(CAMERA, R, mm)
    assert z0 < 0 < 20 < z1 < 6 * R


def test_to_grey_handles_16_bit_and_colour() -> None:
    img = np.full((4, 5, 3), 65535, np.uint16)
    assert np.allclose(to_grey(img), 1.0)
    assert to_grey(np.full((4, 5), 128, np.uint8)).max() == pytest.approx(128 / 255)


def test_to_grey_of_integer_frames_is_the_cast_times_the_scale() -> None:
    """The one-pass conversion does the float32 arithmetic of cast-then-scale exactly."""
    rng = np.random.default_rng(3)
    for dtype in (np.uint8, np.uint16):
        img = rng.integers(0, np.iinfo(dtype).max, (40, 50), endpoint=True).astype(dtype)
        expected = img.astype(np.float32) * np.float32(1.0 / np.iinfo(dtype).max)
        grey = to_grey(img)
        assert grey.dtype == np.float32 and np.array_equal(grey, expected)


def test_shading_is_the_lit_walls_irradiance_relative_to_one_radius_for_the_run() -> None:
    """A frame in a narrower stretch (a reducer) sees its nearer wall brighter: with the
    LEDs at the camera centre on the axis, a wall point at radius r and axial distance z
    gets cos/d² = r/d³ (d² = r² + z²). Two frames unwrapped onto the run's grid, one in
    a 65 mm and one in a 61 mm section: their shadings stand in that ratio (each
    normalised by its own section, the narrow one came out (30.5/32.5)² too dark and the
    exposure solve took it for a darker exposure)."""
    grid = WallGrid.window(R, 0.2, 4.0, 40.0)
    wide, narrow = (unwrap_maps(CAMERA, Pose(), PipeSection(r), grid, with_quality=True)
                    for r in (R, 30.5))
    z = grid.z0_mm + np.arange(grid.n_cols) * grid.mm_per_px_axial
    irradiance = {r: r / np.hypot(r, z) ** 3 for r in (R, 30.5)}
    seen = (wide.quality > 0) & (narrow.quality > 0)
    assert seen.mean() > 0.5
    ratio = np.broadcast_to(irradiance[30.5] / irradiance[R], seen.shape)
    np.testing.assert_allclose((narrow.shading / wide.shading)[seen], ratio[seen], rtol=2e-3)


def test_an_occluder_mask_masks_its_nodes_packed_or_not(renderer: Renderer) -> None:
    # The nodes whose nearest frame pixel is occluded are masked (weight 0, NaN); the
    # mask packed once for a run's strips masks the same nodes.
    _, led = renderer.render_pair(Pose.from_degrees(1, -1, 2, 1, 0, 40.0),
                                  np.random.default_rng(0))
    grey = to_grey(led)
    grid = WallGrid.window(R, default_mm_per_px(CAMERA, R), 0.0, 30.0)
    maps = unwrap_maps(CAMERA, Pose.from_degrees(1, -1, 2, 1, 0, 0), PipeSection(R), grid,
                       step=4, with_quality=True)
    occluded = np.zeros(grey.shape, bool)
    occluded[:, : grey.shape[1] // 2] = True    # the left half of the frame
    free = unwrap_with_quality(grey, maps)
    masked = unwrap_with_quality(grey, maps, occluded=occluded)
    packed = unwrap_with_quality(grey, maps, occluded=pack_mask(occluded))
    np.testing.assert_array_equal(packed.weight, masked.weight)
    np.testing.assert_array_equal(packed.values, masked.values)
    left = np.rint(maps.map_x) < grey.shape[1] // 2
    seen = free.weight > 0
    assert np.any(seen & left) and np.any(seen & ~left)
    assert np.all(masked.weight[left] == 0) and np.all(np.isnan(masked.values[left]))
    np.testing.assert_array_equal(masked.weight[~left], free.weight[~left])
