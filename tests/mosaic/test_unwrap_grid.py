"""Strips on the wall grid: where a wall feature lands, the window of the wall a run
resolves.
"""

from __future__ import annotations

import numpy as np

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose, WallGrid
from pipestitch.mosaic.unwrap import (
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
