"""Unwrap quality and maps, occluders, registration, global solve, refinement, stitching.

Ground truth comes from the simulator's renderer (true poses, true wall) and from
synthetic shifts of a random texture, never from the code under test.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose
from pipestitch.mosaic import Canvas, Overview, _feather, frame_grid, vignetting_profile
from pipestitch.occluder import occluder_mask
from pipestitch.refine import PATCHES_AROUND, node_jacobian, patch_shifts
from pipestitch.register import (
    Link,
    MotionPrior,
    measure_shift,
    registration_image,
    solve_positions,
    spectrum,
    strip_contrast,
)
from pipestitch.simulate.evaluate import WallImage, score_mosaic
from pipestitch.simulate.render import Optics, Renderer, WallTexture
from pipestitch.simulate.textures import WallGrid, make_wall
from pipestitch.unwrap import (
    Strip,
    StripGrid,
    default_mm_per_px,
    polar_unwrap_maps,
    strip_window_mm,
    to_grey,
    unwrap_maps,
    unwrap_with_quality,
)

R = 32.5
CAMERA = default_camera("half")


@pytest.fixture(scope="module")
def wall() -> tuple[WallGrid, np.ndarray]:
    grid = WallGrid.square(R, 0.07, -40.0, 160.0)
    return grid, make_wall("chart", grid, rng=np.random.default_rng(3))


@pytest.fixture(scope="module")
def renderer(wall: tuple[WallGrid, np.ndarray]) -> Renderer:
    grid, albedo = wall
    texture = WallTexture(albedo, grid.deg_per_px, grid.mm_per_px_axial, grid.z0_mm)
    return Renderer(CAMERA, PipeSection.circle(2 * R), texture, 16.0, Optics())


def _truth(wall: tuple[WallGrid, np.ndarray]) -> WallImage:
    grid, albedo = wall
    return WallImage(albedo, grid.deg_per_px, grid.mm_per_px_axial, grid.z0_mm)


def _strip_score(renderer: Renderer, wall: tuple[WallGrid, np.ndarray], true_pose: Pose,
                 used_pose: Pose) -> tuple[float, float]:
    """SSIM and geometric RMS of one LED frame unwrapped with ``used_pose``."""
    _, led = renderer.render_pair(true_pose, np.random.default_rng(0))
    mm = default_mm_per_px(CAMERA, R)
    grid = StripGrid.window(R, mm, 0.0, 30.0)
    maps = unwrap_maps(CAMERA, used_pose, PipeSection(R), grid, step=4, with_quality=True)
    strip = unwrap_with_quality(to_grey(led), maps)
    image = np.where(strip.weight > 0, strip.values / strip.shading, np.nan)
    s = score_mosaic(WallImage(image, grid.deg_per_px, mm, grid.z0_mm), _truth(wall), R,
                     true_pose.z_mm, np.rad2deg(true_pose.roll))
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


def test_coarse_maps_match_exact_projection() -> None:
    grid = StripGrid.window(R, 0.135, -13.0, 50.0)
    pose = Pose.from_degrees(3, -2, 4, -3)
    mx, my = unwrap_maps(CAMERA, pose, PipeSection(R), grid)
    fast = unwrap_maps(CAMERA, pose, PipeSection(R), grid, step=4, with_quality=True)
    ok = (mx >= 0) & (fast.map_x >= 0) & (fast.quality > 0.5)
    assert ok.mean() > 0.3
    assert np.max(np.hypot(mx - fast.map_x, my - fast.map_y)[ok]) < 0.05
    assert np.mean((mx >= 0) != (fast.map_x >= 0)) < 1e-3   # same visible region


def test_quality_falls_with_distance_and_shading_with_offset() -> None:
    grid = StripGrid.window(R, 0.135, 0.0, 60.0)
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
    grid = StripGrid.window(R, 0.2, 5.0, 40.0)
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


def test_occluder_mask_keeps_static_dark_and_drops_moving_dark() -> None:
    rng = np.random.default_rng(0)
    frames = []
    for k in range(7):
        f = (0.5 + 0.2 * cv2.GaussianBlur(rng.random((200, 240)), (0, 0), 2)).astype(np.float32)
        f[:, 100:110] = 0.02                     # the arm: always there
        cv2.circle(f, (30 + 25 * k, 50), 6, 0.02, -1)   # a hole moving with the wall
        frames.append(f)
    mask = occluder_mask(frames)
    assert mask[:, 102:108].all()
    assert not mask[50, 30] and not mask[50, 130]
    assert mask.mean() < 0.15
    # the frames spread over threads give the same mask
    np.testing.assert_array_equal(occluder_mask(frames, workers=3), mask)
    with pytest.raises(ValueError):
        occluder_mask([])
    with pytest.raises(ValueError, match="one size"):
        occluder_mask([frames[0], frames[1][:, :200]])


def _texture(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (0.5 + cv2.GaussianBlur(rng.random(shape), (0, 0), 1.5)).astype(np.float32)


def _shifted(img: np.ndarray, d_rows: float, d_cols: float) -> np.ndarray:
    """img(x + d), rows wrapping (as the pipe does)."""
    rows, cols = np.mgrid[0:img.shape[0], 0:img.shape[1]].astype(np.float32)
    return cv2.remap(img, cols + d_cols, rows + d_rows, cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_WRAP)


def test_registration_recovers_axial_shift_and_roll() -> None:
    grid = StripGrid(360 / 720, 0.1, 0.0, 300)
    wall = _texture((720, 420))
    first = wall[:, :300]
    second = _shifted(wall, 13.4, 37.3)[:, :300]     # frame j: 3.73 mm on, 6.7 deg of roll
    images = [registration_image(strip_contrast(Strip(s, np.ones_like(s), np.ones_like(s))),
                                 np.ones_like(s)) for s in (first, second)]
    link = measure_shift(images[0], images[1], grid, 0, 1)
    assert link is not None
    assert link.dz_mm == pytest.approx(3.73, abs=0.01)
    assert link.droll_deg == pytest.approx(13.4 * 0.5, abs=0.01)
    assert measure_shift(images[0], np.zeros_like(images[1]), grid, 0, 1) is None


@pytest.mark.parametrize("shape", [(720, 300), (675, 300), (720, 243), (675, 243)])
def test_registration_with_a_motion_prior_on_strips_of_any_parity(
        shape: tuple[int, int]) -> None:
    # The correlation runs on packed spectra, whose layout depends on the parity of
    # both sizes; the prior (odometer-like, 0.3 mm and 0.5 deg off) must not bias it.
    n_rows, n_cols = shape
    grid = StripGrid(360 / n_rows, 0.1, 0.0, n_cols)
    wall = _texture((n_rows, n_cols + 120), seed=1)
    second = _shifted(wall, 13.4, 37.3)[:, :n_cols]
    images = [registration_image(strip_contrast(Strip(s, np.ones_like(s), np.ones_like(s))),
                                 np.ones_like(s)) for s in (wall[:, :n_cols], second)]
    droll = 13.4 * grid.deg_per_px
    prior = MotionPrior(3.73 + 0.3, droll + 0.5, 3.0, 5.0)
    link = measure_shift(images[0], images[1], grid, 0, 1, prior,
                         (spectrum(images[0]), spectrum(images[1])))
    assert link is not None
    # One Lucas-Kanade step from the whole-pixel peak: ~0.02 px measured, 0.05 px allowed.
    assert link.dz_mm == pytest.approx(3.73, abs=0.005)
    assert link.droll_deg == pytest.approx(droll, abs=0.05 * grid.deg_per_px)


def _link(i: int, j: int, dz: float, droll: float = 0.0) -> Link:
    return Link(i, j, dz, droll, 0.5, 0.02, 0.02)


def test_global_solve_outvotes_a_bad_link_and_an_odometer_slip() -> None:
    z_true = np.array([0.0, 5.1, 9.8, 15.2, 20.0, 25.3])
    roll_true = np.array([0.0, 0.3, 0.5, 0.6, 0.5, 0.2])
    links = [_link(i, j, z_true[j] - z_true[i], roll_true[j] - roll_true[i])
             for i in range(6) for j in (i + 1, i + 2) if j < 6]
    links[3] = dataclasses.replace(links[3], dz_mm=links[3].dz_mm + 4.0)   # a wrong peak
    odometer = {i: 1.02 * (z - 0.0) + 100.0 for i, z in enumerate(z_true)}
    odometer.update({k: v - 3.0 for k, v in odometer.items() if k >= 4})  # the wheel slips
    pos = solve_positions(6, links, odometry_mm=odometer)
    dz = np.diff(pos.z_mm)
    assert np.allclose(dz, np.diff(z_true), atol=0.01)
    assert np.allclose(pos.roll_deg - pos.roll_deg[0], roll_true, atol=0.01)
    assert (links[3].i, links[3].j, "registration") in pos.outliers
    assert any(src == "odometer" for *_, src in pos.outliers)


def test_roll_of_frames_tied_only_by_the_odometer_is_interpolated_and_reported() -> None:
    links = [_link(0, 1, 5.0, 10.0), _link(2, 3, 5.0, 10.0)]
    pos = solve_positions(4, links, odometry_mm={i: 5.0 * i for i in range(4)})
    assert np.allclose(np.diff(pos.z_mm), 5.0, atol=1e-6)
    assert pos.roll_deg[0] == pytest.approx(0.0, abs=1e-6)
    assert pos.roll_deg[1] == pytest.approx(10.0, abs=1e-3)
    assert pos.roll_deg[3] - pos.roll_deg[2] == pytest.approx(10.0, abs=1e-3)
    assert sorted(pos.roll_guessed) == [2, 3]


def test_a_frame_whose_only_links_are_rejected_is_not_placed() -> None:
    """Frame 4's two links disagree by 10 mm: neither can be trusted, so it is left out
    instead of being put somewhere in between."""
    good = [_link(0, 1, 5.0), _link(1, 2, 5.0), _link(0, 2, 10.0), _link(1, 3, 10.0),
            _link(2, 3, 5.0)]
    pos = solve_positions(5, [*good, _link(3, 4, 5.0), _link(2, 4, 20.0)])
    assert np.allclose(pos.z_mm[:4], [0.0, 5.0, 10.0, 15.0], atol=1e-6)
    assert np.isnan(pos.z_mm[4])
    assert {(3, 4, "registration"), (2, 4, "registration")} <= set(pos.outliers)


def test_global_solve_leaves_unconnected_frames_unplaced() -> None:
    links = [_link(0, 1, 5.0), _link(1, 2, 5.0), _link(3, 4, 5.0)]
    pos = solve_positions(5, links)
    assert np.all(np.isfinite(pos.z_mm[:3])) and np.all(np.isnan(pos.z_mm[3:]))
    pos = solve_positions(5, links, odometry_mm={i: 5.0 * i for i in range(5)})
    assert np.allclose(np.diff(pos.z_mm), 5.0, atol=1e-6)


def test_patch_shifts_measure_local_motion() -> None:
    wall = _texture((400, 400), seed=2)
    first = wall[:, :300] - 0.5
    second = (_shifted(wall, 3.0, 20.25)[:, :300] - 0.5).astype(np.float32)
    valid = np.ones_like(first, bool)
    found = patch_shifts(first, valid, second, valid, (3.0, 20.0), 0, 1)
    assert len(found.nodes) > 10
    assert np.allclose(found.shift, [3.0, 20.25], atol=0.05)
    # a strip of many rows (a full-size sensor's) gets at most PATCHES_AROUND around
    tall = np.vstack([first] * 8)
    found = patch_shifts(tall, np.ones_like(tall, bool), np.vstack([second] * 8),
                         np.ones_like(tall, bool), (3.0, 20.0), 0, 1)
    rows = np.unique(found.nodes[:, 0])
    assert np.all(np.diff(rows) == tall.shape[0] // PATCHES_AROUND)
    assert PATCHES_AROUND <= len(rows) <= PATCHES_AROUND + 1   # the step rounds down
    assert np.allclose(found.shift, [3.0, 20.25], atol=0.05)


def test_node_jacobian_predicts_the_strip_warp_of_a_pose_error() -> None:
    """Unwrap one frame with the true pose and with a slightly wrong one: the wall
    moves between the two strips by G·e, as node_jacobian says."""
    grid = StripGrid.window(R, 0.135, 5.0, 40.0)
    true = Pose.from_degrees(1.0, -0.5, 2.0, 1.0)
    error = np.array([np.deg2rad(0.3), np.deg2rad(-0.2), 0.1, -0.05])
    wrong = Pose(true.alpha + error[0], true.beta + error[1], true.dx_mm + error[2],
                 true.dy_mm + error[3])
    nodes = np.array([[100.0, 50.0], [600.0, 120.0], [1200.0, 200.0]])
    g = node_jacobian(CAMERA, wrong, PipeSection(R), grid, nodes)
    # Ground truth: where the wrong strip's node really is on the wall, found by
    # projecting it with the wrong pose and locating that pixel in the true strip.
    mx_t, my_t = unwrap_maps(CAMERA, true, PipeSection(R), grid)
    mx_w, my_w = unwrap_maps(CAMERA, wrong, PipeSection(R), grid)
    for (r, c), gn in zip(nodes.astype(int), g, strict=True):
        px = np.array([mx_w[r, c], my_w[r, c]])
        d = np.hypot(mx_t - px[0], my_t - px[1])
        rr, cc = np.unravel_index(np.argmin(d), d.shape)
        predicted = np.array([r, c]) + gn @ error
        assert np.allclose(predicted, [rr, cc], atol=1.0)


def test_frame_grid_places_frames_by_z_and_roll() -> None:
    canvas_grid = StripGrid(0.5, 0.1, -10.0, 1000)
    grid, col = frame_grid(canvas_grid, 12.34, 2.0, (-5.0, 30.0))
    assert grid.theta0_deg == -2.0
    assert canvas_grid.z0_mm + col * 0.1 - 12.34 == pytest.approx(grid.z0_mm)
    assert grid.z0_mm >= -5.0 and grid.z0_mm + (grid.n_cols - 1) * 0.1 <= 30.0


def test_canvas_blends_seamlessly_across_theta_zero_and_compensates_gain() -> None:
    grid = StripGrid(1.0, 0.1, 0.0, 120)
    canvas = Canvas(grid)
    level = np.ones(80)
    wall = _texture((360, 120), seed=5)
    ones = np.ones((360, 80), np.float32)
    canvas.add(Strip(wall[:, :80].copy(), ones, ones), 0, level)
    gain = canvas.add(Strip(2.0 * wall[:, 40:120], ones, ones), 40, level)
    image, weights = canvas.image()
    assert np.all(weights > 0)
    assert gain == pytest.approx(0.5, rel=0.02)
    assert np.allclose(image, wall, atol=0.02)
    feather = _feather(np.ones((360, 80), bool))
    assert feather[0, 40] == 1.0 and feather[-1, 40] == 1.0   # rows wrap: no seam at 0/360
    assert feather[100, 0] < 0.1


def test_canvas_released_in_blocks_equals_the_whole_canvas() -> None:
    """Streaming: columns released as soon as no later strip reaches them give exactly
    the mosaic of a canvas held whole, and the window stays the width of the strips."""
    grid = StripGrid(1.0, 0.1, 0.0, 2000)
    wall = _texture((360, 2000), seed=7)
    ones = np.ones((360, 300), np.float32)
    starts = list(range(0, 1701, 100))
    whole, streamed = Canvas(grid), Canvas(grid)
    blocks, widest = [], 0
    for k, c in enumerate(starts):
        strip = Strip((1 + 0.1 * (k % 3)) * wall[:, c:c + 300], ones, ones)
        whole.add(strip, c, np.ones(300))
        streamed.add(strip, c, np.ones(300))
        widest = max(widest, streamed.total.shape[1])
        nxt = starts[k + 1] if k + 1 < len(starts) else None
        got = streamed.release(nxt)
        if got is not None:
            blocks.append(got)
    image, weights = whole.image()
    assert [b[0] for b in blocks] == starts      # released up to the next strip each time
    assert np.array_equal(np.concatenate([b[1] for b in blocks], axis=1), image, equal_nan=True)
    assert np.array_equal(np.concatenate([b[2] for b in blocks], axis=1), weights)
    assert widest <= 300 + 512
    with pytest.raises(ValueError, match="released"):
        streamed.add(Strip(wall[:, :300], ones, ones), 0, np.ones(300))


def test_overview_keeps_the_wall_image_convention() -> None:
    """A reduced mosaic.png: row i at theta = i x its deg_per_px, column j at its z0 +
    j x its mm_per_px, values the local mean; half-seen groups are data, others 0."""
    grid = StripGrid(360 / 1500, 0.135, -12.0, 5003)
    theta = np.arange(1500)[:, None] * grid.deg_per_px
    z = grid.z0_mm + np.arange(5003)[None, :] * grid.mm_per_px
    image = np.rint(128 + 60 * np.sin(np.deg2rad(theta)) + 0.1 * z).astype(np.uint8)
    image[:, 4000:4003] = 0                       # three unseen columns
    ov = Overview(grid, max_pixels=1_000_000)
    for c in range(0, 5003, 700):
        ov.push(image[:, c:c + 700])
    out = ov.finish()
    f, g = ov.factor, ov.grid
    assert f == 3 and out.shape == (g.n_rows, g.n_cols) == (500, 1668)
    th = np.arange(g.n_rows)[:, None] * g.deg_per_px
    zz = g.z0_mm + np.arange(g.n_cols)[None, :] * g.mm_per_px
    expect = 128 + 60 * np.sin(np.deg2rad(th)) + 0.1 * zz
    data = out > 0
    assert np.abs(out[data] - np.broadcast_to(expect, out.shape)[data]).max() <= 1.01
    assert not data[:, 4000 // 3].any() and data[:, 4003 // 3 + 1].all()


def test_vignetting_profile_of_a_long_run_from_a_bounded_sample_of_frames(monkeypatch) -> None:
    """A long run's profile is the median over PROFILE_FRAMES evenly spaced frames: the
    vignetting (here a falloff to 0.6 at the ends, under ±10 % exposure changes and 5 %
    noise a frame) comes out to 0.5 % RMS, as from all frames, and the frames between
    the sampled ones are not read."""
    from pipestitch import mosaic

    rng = np.random.default_rng(4)
    z = np.linspace(-1, 1, 300)
    falloff = 1.0 - 0.4 * z**2
    levels = [(falloff * rng.uniform(0.9, 1.1) * rng.normal(1, 0.05, z.size)).astype(np.float32)
              for _ in range(3000)]
    for lv in levels[::7]:
        lv[:40] = np.nan                     # columns some frames do not see
    expected = falloff / np.median(falloff)
    sampled = vignetting_profile(levels)
    assert len(levels) > 5 * mosaic.PROFILE_FRAMES
    assert np.sqrt(np.mean((sampled - expected) ** 2)) < 0.005   # ~0.3 % a column
    step = -(-len(levels) // mosaic.PROFILE_FRAMES)
    assert mosaic.profile_step(len(levels)) == step   # what a pass keeps of a run's levels
    np.testing.assert_array_equal(vignetting_profile(levels[::step]), sampled)
    garbled = [lv if k % step == 0 else np.full_like(lv, 7.0) for k, lv in enumerate(levels)]
    np.testing.assert_array_equal(vignetting_profile(garbled), sampled)
    monkeypatch.setattr(mosaic, "PROFILE_FRAMES", len(levels))
    assert np.sqrt(np.mean((vignetting_profile(levels) - expected) ** 2)) < 0.005


def test_another_round_follows_a_large_tilt_correction_or_new_ovals() -> None:
    """One refinement round is linearised about its starting poses: one that moved a
    tilt by more than LINEAR_TILT_DEG, or found frames oval that it had registered as
    circles, is followed by another; small corrections are not."""
    from pipestitch.pipeline.mosaic import LINEAR_TILT_DEG, FrameView, _another_round

    section = PipeSection(32.5)
    before = {0: FrameView(Pose(0.01, 0.0, 1.0, 0.0), section),
              1: FrameView(Pose(0.0, 0.02, 0.0, 1.0), section)}
    small = np.deg2rad(0.5 * LINEAR_TILT_DEG)
    after = {0: FrameView(Pose(0.01 + small, 0.0, 1.2, 0.0), section),
             1: FrameView(Pose(0.0, 0.02 - small, 0.0, 1.0), section)}
    assert not _another_round(before, after)
    large = np.deg2rad(1.5 * LINEAR_TILT_DEG)
    assert _another_round(before, {**after, 1: FrameView(Pose(0.0, 0.02 - large, 0, 1),
                                                         section)})
    assert _another_round(before, {**after, 0: FrameView(after[0].pose, section, oval=True)})
    oval_before = {**before, 0: FrameView(before[0].pose, section, oval=True)}
    assert not _another_round(oval_before, {**after, 0: FrameView(after[0].pose, section,
                                                                  oval=True)})
