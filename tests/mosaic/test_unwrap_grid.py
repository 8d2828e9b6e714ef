"""Strips on the wall grid: where a wall feature lands, the window of the wall a run
resolves.
"""

from __future__ import annotations

import numpy as np

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose, WallGrid
from pipestitch.mosaic.unwrap import (
    _node_fields,
    default_mm_per_px,
    seen_window_mm,
    strip_window_mm,
    unwrap,
    unwrap_maps,
    unwrap_with_quality,
)
from pipestitch.pose.ring import prepare_laser_frame
from pipestitch.simulate.render import Renderer

R = 32.5


def test_unwrapped_hole_lands_at_its_wall_position(holed_renderer: Renderer) -> None:
    pose = Pose.from_degrees(2.5, -1.5, 3.0, -2.0, 0.0, 20.0)
    _, led = holed_renderer.render_pair(pose, np.random.default_rng(1))
    grid = WallGrid.window(R, 0.1, 20.0, 70.0)
    strip = unwrap(prepare_laser_frame(led), holed_renderer.camera, pose, PipeSection(R), grid)
    # The hole at theta = 200°, world z = 60 mm is 40 mm ahead of the camera (roll 0).
    row, col = round(200.0 / grid.deg_per_px), round((40.0 - grid.z0_mm) / grid.mm_per_px_axial)
    patch = strip[row - 60:row + 61, col - 60:col + 61]
    dark = patch < 0.3 * np.nanmedian(patch)
    rr, cc = np.nonzero(dark)
    # Its centre is within 0.3 mm of the truth, its area that of a 6 mm hole (+-15 %).
    assert abs(rr.mean() - 60) * 0.1 < 0.3 and abs(cc.mean() - 60) * 0.1 < 0.3
    area = dark.sum() * 0.1 * 0.1
    assert np.pi * 9 * 0.85 < area < np.pi * 9 * 1.15


def test_seen_window_keeps_every_resolved_node_and_cuts_the_rest() -> None:
    """Strips over the centred camera's widened window, unwrapped node by node (step 1)
    for tilted and offset frames: every node they keep lies inside the run's seen
    window, and the seen window is markedly shorter (the cost of every strip)."""
    cam = default_camera("half")
    section = PipeSection.circle(2 * R)
    mm = default_mm_per_px(cam, R)
    window = strip_window_mm(cam, R, mm)
    poses = [Pose(), Pose.from_degrees(6.0, -3.0, 5.0, -4.0, 0.0, 0.0),
             Pose.from_degrees(-4.0, 7.0, -8.0, 2.0, 0.0, 0.0)]
    seen = seen_window_mm(cam, [(p, section) for p in poses], R, mm, window)
    assert window[0] <= seen[0] < seen[1] <= window[1]
    assert seen[1] - seen[0] < 0.85 * (window[1] - window[0])
    grid = WallGrid.window(R, mm, *window)
    frame = np.ones((cam.height, cam.width), np.float32)
    z = grid.z0_mm + np.arange(grid.n_cols) * grid.mm_per_px_axial
    for pose in poses:
        strip = unwrap_with_quality(frame, unwrap_maps(cam, pose, section, grid, step=1,
                                                       with_quality=True))
        kept = z[(strip.weight > 0).any(axis=0)]
        assert kept.size and seen[0] <= kept.min() and kept.max() <= seen[1]
    # nothing resolved at all: the window is kept as it is
    far = Pose(0.0, 0.0, 0.0, 0.0)
    assert seen_window_mm(cam, [(far, section)], R, 50.0, window,
                          min_resolution=1e9) == window


def _seen_window_everywhere(cam, views, radius_mm, mm_per_px, window, occluded, step):
    """seen_window_mm's answer from every view evaluated at every node column."""
    grid = WallGrid.window(radius_mm, mm_per_px, *window)
    lo, hi = np.inf, -np.inf
    for pose, section in views:
        nodes, z = _node_fields(cam, pose, section, grid, step, True)
        col, row = np.rint(nodes.map_x).astype(int), np.rint(nodes.map_y).astype(int)
        good = ((nodes.valid > 0) & (nodes.quality >= 0.5) & (col >= 0) & (col < cam.width)
                & (row >= 0) & (row < cam.height))
        if occluded is not None:
            good[good] = ~occluded[row[good], col[good]]
        seen = np.flatnonzero(good.any(axis=0))
        if seen.size:
            lo, hi = min(lo, z[seen[0]]), max(hi, z[seen[-1]])
    if not np.isfinite(lo):
        return window
    pad = step * mm_per_px + 2.0
    return max(window[0], float(lo) - pad), min(window[1], float(hi) + pad)


def _random_views(rng: np.random.Generator, n: int) -> list[tuple[Pose, PipeSection]]:
    views = []
    for _ in range(n):
        pose = Pose.from_degrees(*rng.uniform(-8, 8, 2), *rng.uniform(-9, 9, 2), 0.0, 0.0)
        oval = rng.uniform(0, 0.04)
        views.append((pose, PipeSection(R * (1 + oval), R * (1 - oval), rng.uniform(0, np.pi))
                      if rng.random() < 0.3 else PipeSection(R * rng.uniform(0.97, 1.03))))
    return views


def test_seen_window_evaluates_only_the_columns_that_can_widen_it() -> None:
    """Each view is evaluated only outside the columns already resolved: the window is
    the one every view evaluated everywhere gives, to the bit, for random tilted,
    offset and oval views in any order, with and without occluded pixels, at several
    node steps and scales; and a node column evaluated beside others than its grid
    neighbours keeps its fields wherever both its neighbours are its own."""
    cam = default_camera("half")
    mm = default_mm_per_px(cam, R)
    window = strip_window_mm(cam, R, mm)
    rng = np.random.default_rng(7)
    occluded = np.zeros((cam.height, cam.width), bool)
    for _ in range(12):   # blobs of pixels no view may count as resolved
        r, c = rng.integers(0, cam.height), rng.integers(0, cam.width)
        occluded[max(r - 60, 0):r + 60, max(c - 90, 0):c + 90] = True
    for k in range(6):
        views = _random_views(rng, 25)
        for mask in (None, occluded):
            for step, scale in ((16, 1), (16, 2), (4, 1)):
                args = (cam, views, R, mm * scale, window)
                assert (seen_window_mm(*args, occluded=mask, step=step)
                        == _seen_window_everywhere(*args, mask, step)), (k, step, scale)
    grid = WallGrid.window(R, mm, *window)
    pose, section = _random_views(rng, 1)[0]
    whole, z = _node_fields(cam, pose, section, grid, 16, True)
    columns = np.r_[np.arange(6), np.arange(11, z.size)]
    part, z_part = _node_fields(cam, pose, section, grid, 16, True, columns=columns)
    np.testing.assert_array_equal(z_part, z[columns])
    inner = [k for k, c in enumerate(columns) if c not in (5, 11)]   # not beside the cut
    for field_whole, field_part in zip(whole, part, strict=True):
        np.testing.assert_array_equal(field_part[:, inner], field_whole[:, columns[inner]])
