"""Where the ring leaves the fitted section (pose/departure.py): a dent found, measured
and placed; a round wall, noise or a ring crossing a hole report nothing."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose, laser_ring
from pipestitch.pose.departure import ring_departures
from pipestitch.pose.fit import LaserPlane, fit_pose
from pipestitch.pose.ring import RingDetection

D = 16.0
RADIUS = 32.5
N_RAYS = 1440


def _dented_ring(pose: Pose, depth_mm: float, theta_deg: float, half_width_deg: float,
                 noise_px: float = 0.1, seed: int = 0) -> tuple[RingDetection, object]:
    """One candidate per ray on a wall whose radius is R - depth * cos^2 over
    ``half_width_deg`` about world angle ``theta_deg``: each ring point moved along its
    plane ray between the ring of radius R and that of R - depth, by the dent's share
    at the point's world angle."""
    cam = default_camera("full")
    phi = np.linspace(0, 2 * np.pi, N_RAYS, endpoint=False)
    outer = laser_ring(pose, PipeSection(RADIUS), D, phi=phi)
    inner = laser_ring(pose, PipeSection(RADIUS - abs(depth_mm)), D, phi=phi)
    world = pose.to_world(outer)
    off = (np.degrees(np.arctan2(world[:, 1], world[:, 0])) - theta_deg + 180) % 360 - 180
    share = np.where(np.abs(off) < half_width_deg,
                     np.cos(np.pi / 2 * off / half_width_deg) ** 2, 0.0)
    towards = inner if depth_mm < 0 else 2 * outer - inner
    points = outer + share[:, None] * (towards - outer)
    pixels = cam.project(points) + np.random.default_rng(seed).normal(0, noise_px, (N_RAYS, 2))
    centre = cam.project(np.array([[0.0, 0.0, 1.0]]))[0]
    azimuth = np.round(np.mod(np.arctan2(pixels[:, 1] - centre[1], pixels[:, 0] - centre[0]),
                              2 * np.pi) / (2 * np.pi) * N_RAYS).astype(int) % N_RAYS
    order = np.argsort(azimuth, kind="stable")
    return RingDetection(pixels[order], azimuth[order], np.zeros(N_RAYS, int),
                         np.full(N_RAYS, 30.0), N_RAYS, 0.01, line_sigma_px=1.0), cam


def _departure(det: RingDetection, cam) -> tuple[object, object]:
    fit = fit_pose(det, cam, D, nominal_radius_mm=RADIUS)
    assert fit.ok
    h = fit.hypotheses[0]
    return ring_departures(det, [(h.pose, h.pipe_section)], cam, LaserPlane.of(D),
                           fit.ring.noise_mm)[0], h


@pytest.mark.parametrize("pose", [Pose.from_degrees(), Pose.from_degrees(2.0, -1.5, 3.0, -2.0)])
@pytest.mark.parametrize("depth", [-2.0, -1.0, 1.0])
def test_a_dent_is_measured_where_it_is(pose: Pose, depth: float) -> None:
    det, cam = _dented_ring(pose, depth, 250.0, 40.0)
    dep, h = _departure(det, cam)
    assert dep is not None
    assert dep.depth_mm == pytest.approx(depth, abs=0.1)
    # the fit keeps the round part of the ring: the pipe's radius
    assert h.radius_mm == pytest.approx(RADIUS, abs=0.05)
    # its angle in the hypothesis' frame: the true one, or the mirror's (-alpha, -beta)
    world = [250.0, (250.0 + 180.0) % 360.0] if pose.tilt > 0 else [250.0]
    assert min(abs((dep.theta_deg - w + 180) % 360 - 180) for w in world) < 5.0
    assert 30.0 < dep.extent_deg < 80.0
    if depth < 0:
        assert dep.min_radius_mm == pytest.approx(RADIUS + depth, abs=0.1)
    else:
        assert dep.max_radius_mm == pytest.approx(RADIUS + depth, abs=0.1)


def test_a_round_wall_or_a_shallow_dent_departs_nowhere() -> None:
    pose = Pose.from_degrees(1.0, 2.0, -2.0, 1.0)
    for depth in (0.0, -0.1):   # within the fit's own noise
        det, cam = _dented_ring(pose, depth if depth else -1e-9, 90.0, 40.0, noise_px=0.2)
        assert _departure(det, cam)[0] is None


def test_a_ring_crossing_a_hole_is_no_dent() -> None:
    """A hole: the line jumps about and is missing on some of its rays."""
    pose = Pose.from_degrees(1.0, 2.0, -2.0, 1.0)
    det, cam = _dented_ring(pose, 0.0 - 1e-9, 90.0, 40.0)
    rng = np.random.default_rng(3)
    k = np.flatnonzero((det.azimuth >= 300) & (det.azimuth < 330))
    pixels = det.pixels.copy()
    pixels[k] += rng.uniform(-8, 8, (len(k), 2))
    keep = np.ones(len(pixels), bool)
    keep[k[::3]] = False
    holed = RingDetection(pixels[keep], det.azimuth[keep], det.rank[keep], det.snr[keep],
                          N_RAYS, 0.01, line_sigma_px=1.0)
    assert _departure(holed, cam)[0] is None


def test_rays_without_a_candidate_take_the_angle_between_their_neighbours() -> None:
    """Across ray 0 too: not half a turn off (the angles wrap there)."""
    from pipestitch.pose.departure import _ray_angles

    rays = np.array([k for k in range(N_RAYS) if k not in (0, 1, N_RAYS - 1)])
    theta = 2 * np.pi * rays / N_RAYS + 0.1          # the world angle of each ray's point
    det = RingDetection(np.zeros((len(rays), 2)), rays, np.zeros(len(rays), int),
                        np.ones(len(rays)), N_RAYS, 0.01)
    xy = np.stack([np.cos(theta), np.sin(theta)], 1)
    angle = _ray_angles(det, xy, np.ones(len(rays), bool))
    expected = 2 * np.pi * np.array([0, 1, N_RAYS - 1]) / N_RAYS + 0.1
    off = (angle[[0, 1, N_RAYS - 1]] - expected + np.pi) % (2 * np.pi) - np.pi
    assert np.all(np.abs(off) < 1e-3)
