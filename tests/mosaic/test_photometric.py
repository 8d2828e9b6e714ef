"""Photometric evidence on the mirror ambiguity: the true pair of LED frames agrees best."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose, laser_ring
from pipestitch.mosaic.photometric import contrast_strips, pair_costs
from pipestitch.pose.fit import ConicModel, Hypothesis, PoseFit, pose_from_conic
from pipestitch.pose.ring import prepare_laser_frame
from pipestitch.simulate.render import Optics, Renderer, WallTexture
from pipestitch.simulate.textures import Defect, WallGrid, make_wall

R = 32.5


@pytest.fixture(scope="module")


def renderer() -> Renderer:
    grid = WallGrid.square(R, 0.07, -40.0, 200.0)
    albedo = make_wall("corrosion", grid, rng=np.random.default_rng(0),
                       defects=[Defect("hole", 60.0, 200.0, 6.0)])
    wall = WallTexture(albedo, grid.deg_per_px, grid.mm_per_px_axial, grid.z0_mm)
    return Renderer(default_camera("half"), PipeSection.circle(2 * R), wall, 16.0,
                    Optics(full_well_e=1e9))


def _fit_of(poses: list[Pose]) -> PoseFit:
    return PoseFit(True, "", tuple(Hypothesis(p, R, 0.0, 0.0, 0.0) for p in poses), 100, 1.0)


def test_photometric_costs_prefer_the_true_pair(renderer: Renderer) -> None:
    # Two frames 5 mm apart with 3° of tilt; each "fit" holds the truth and its mirror
    # (-alpha, -beta, offset moved so the ring stays the same, from the ring's conic).
    strips = []
    for z in (20.0, 25.0):
        pose = Pose.from_degrees(2.4, -1.8, 3.0, -2.0, 0.0, z)
        ring = laser_ring(pose, PipeSection(R), 16.0, n_points=90)
        sols = pose_from_conic(*ConicModel.from_estimate(ring[:, :2]).normalised(), 16.0)
        true_first = sorted(sols, key=lambda s: abs(s[0].alpha - pose.alpha))
        _, led = renderer.render_pair(pose, np.random.default_rng(int(z)))
        fit = _fit_of([p for p, _ in true_first])
        strips.append(contrast_strips(prepare_laser_frame(led), renderer.camera, fit))
    costs = pair_costs(*strips)
    assert costs[0, 0] == 0.0
    assert costs[1, 1] > 5 and costs[0, 1] > 5 and costs[1, 0] > 5
