"""Probe geometry against independent closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipestitch.geometry import (
    PipeSection,
    Pose,
    RadiusProfile,
    laser_ring,
    ray_wall_distance,
    rays_to_wall,
    theta_z_from_points,
)
from pipestitch.geometry.rotations import rot_x, rot_y, rot_z


def spec_transform(p: np.ndarray, a: float, b: float, dx: float, dy: float, g: float,
                   z: float) -> np.ndarray:
    """SPEC's pose equation written out with explicit matrices (independent of the code)."""
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(g), -np.sin(g), 0], [np.sin(g), np.cos(g), 0], [0, 0, 1]])
    return (rz @ (rx @ ry @ p.T + np.array([[dx], [dy], [0]]))).T + [0, 0, z]


def test_pose_matches_spec_equation() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)) * 20
    for _ in range(20):
        a, b, g = rng.uniform(-0.5, 0.5, 3)
        dx, dy, z = rng.uniform(-10, 10, 3)
        pose = Pose(a, b, dx, dy, g, z)
        np.testing.assert_allclose(pose.to_world(pts), spec_transform(pts, a, b, dx, dy, g, z),
                                   atol=1e-12)
        np.testing.assert_allclose(pose.to_probe(pose.to_world(pts)), pts, atol=1e-12)


def test_pose_degrees_and_validation() -> None:
    pose = Pose.from_degrees(2.0, -3.0, 1.0, 2.0, 45.0, 7.0)
    assert pose.as_degrees() == pytest.approx(
        {"alpha_deg": 2.0, "beta_deg": -3.0, "dx_mm": 1.0, "dy_mm": 2.0, "z_mm": 7.0,
         "roll_deg": 45.0})
    with pytest.raises(ValueError, match="finite"):
        Pose(float("nan"))


def test_centred_ring_is_circle_of_radius_r_at_d() -> None:
    ring = laser_ring(Pose(), PipeSection.circle(65.0), 16.0, n_points=360)
    np.testing.assert_allclose(ring[:, 2], 16.0, atol=1e-12)
    np.testing.assert_allclose(np.hypot(ring[:, 0], ring[:, 1]), 32.5, atol=1e-12)


@pytest.mark.parametrize("alpha_deg,beta_deg", [(5.0, 0.0), (0.0, -7.0), (3.0, 4.0)])
def test_tilted_ring_is_ellipse_with_axes_r_and_r_over_cos(alpha_deg: float,
                                                           beta_deg: float) -> None:
    a, b = np.deg2rad(alpha_deg), np.deg2rad(beta_deg)
    pose = Pose(a, b, 2.0, -1.5)
    ring = laser_ring(pose, PipeSection.circle(65.0), 16.0, n_points=4000)
    # The ellipse centre is where the pipe axis crosses the plane z = d. In the probe
    # frame the axis is the line through -R^T t with direction R^T e3.
    rot = spec_transform(np.eye(3), a, b, 0, 0, 0, 0).T  # columns: images of e1, e2, e3
    t = np.array([2.0, -1.5, 0.0])
    origin, direction = -rot.T @ t, rot.T @ [0, 0, 1]
    centre = origin + (16.0 - origin[2]) / direction[2] * direction
    dist = np.linalg.norm(ring - centre, axis=1)
    cos_tilt = np.cos(a) * np.cos(b)  # angle between the optical axis and the pipe axis
    # 4000 samples: the extreme distances are found to ~1e-6 mm.
    assert dist.min() == pytest.approx(32.5, abs=1e-5)
    assert dist.max() == pytest.approx(32.5 / cos_tilt, abs=1e-5)


@settings(max_examples=60, deadline=None)
@given(a=st.floats(-0.2, 0.2), b=st.floats(-0.2, 0.2), dx=st.floats(-8, 8), dy=st.floats(-8, 8),
       g=st.floats(-3.2, 3.2), ovality=st.floats(0.0, 0.1), angle=st.floats(0, 3.2))
def test_ring_lies_on_plane_and_wall(a, b, dx, dy, g, ovality, angle) -> None:
    section = PipeSection.oval(65.0, ovality, angle)
    pose = Pose(a, b, dx, dy, g, 12.0)
    ring = laser_ring(pose, section, 16.0, n_points=90)
    np.testing.assert_allclose(ring[:, 2], 16.0, atol=1e-9)
    w = spec_transform(ring, a, b, dx, dy, g, 12.0)
    c, s = np.cos(angle), np.sin(angle)
    u, v = c * w[:, 0] + s * w[:, 1], -s * w[:, 0] + c * w[:, 1]
    np.testing.assert_allclose((u / section.a_mm) ** 2 + (v / section.b_mm) ** 2, 1.0, atol=1e-9)


def test_oval_section_parameters() -> None:
    sec = PipeSection.oval(65.0, 0.04, angle=0.3)
    assert sec.ovality == pytest.approx(0.04)
    assert sec.mean_radius_mm == pytest.approx(32.5)
    theta = np.array([0.3, 0.3 + np.pi / 2])
    np.testing.assert_allclose(sec.radius_at(theta), [sec.a_mm, sec.b_mm], rtol=1e-12)
    assert PipeSection.circle(50).is_circle
    with pytest.raises(ValueError, match="positive"):
        PipeSection(-1.0)


def test_rays_hit_the_wall_forward() -> None:
    rng = np.random.default_rng(1)
    section = PipeSection.oval(80.0, 0.06, 1.0)
    pose = Pose(0.05, -0.08, 5.0, -4.0, 0.7, 100.0)
    rays = rng.normal(size=(5000, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    pts = rays_to_wall(rays, pose, section)
    np.testing.assert_allclose(section.clearance_mm(pts), 0.0, atol=1e-9)
    # Each hit lies in front along its ray: (hit - camera) parallel to the world ray.
    world_dirs = rays @ pose.rotation_world_probe().T
    offset = pts - pose.translation_world_probe()
    assert np.all(np.sum(offset * world_dirs, axis=1) > 0)
    np.testing.assert_allclose(np.linalg.norm(np.cross(offset, world_dirs), axis=1), 0, atol=1e-9)


def test_ray_along_axis_or_origin_outside_gives_nan() -> None:
    section = PipeSection.circle(65.0)
    s = ray_wall_distance(np.zeros(3), np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), section)
    assert np.isnan(s[0]) and s[1] == pytest.approx(32.5)
    assert np.isnan(ray_wall_distance(np.array([40.0, 0, 0]), np.array([[1.0, 0, 0]]), section)[0])


def test_theta_z_round_trip() -> None:
    section = PipeSection.oval(65.0, 0.03, 0.4)
    theta = np.linspace(0, 2 * np.pi, 37)[:-1]
    z = np.linspace(-5, 5, 36)
    th, zz = theta_z_from_points(section.points(theta, z))
    np.testing.assert_allclose(th, theta, atol=1e-12)
    np.testing.assert_allclose(zz, z)
    pts = section.points(theta, z)
    n = section.normals(pts)
    # Independent: the inward normal of (u/a)² + (v/b)² = 1 in the ellipse's own axes.
    c, s = np.cos(0.4), np.sin(0.4)
    u, v = c * pts[:, 0] + s * pts[:, 1], -s * pts[:, 0] + c * pts[:, 1]
    gu, gv = -u / section.a_mm**2, -v / section.b_mm**2
    expected = np.stack([c * gu - s * gv, s * gu + c * gv], axis=1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(n[:, :2], expected, atol=1e-12)
    np.testing.assert_allclose(n[:, 2], 0.0)


def test_rays_meet_a_wall_whose_radius_changes_along_the_pipe() -> None:
    # A reducer (scale 1 -> 0.9 between z 20 and 40 mm) in an oval pipe: every hit lies on
    # the scaled section at its own z; a profile of one scale is the plain section.
    section = PipeSection.oval(65.0, 0.04, angle=0.3)
    profile = RadiusProfile(np.array([0.0, 20.0, 40.0]), np.array([1.0, 1.0, 0.9]))
    dirs = np.random.default_rng(0).normal(size=(20000, 3))
    origin = np.array([3.0, -2.0, 25.0])
    s = ray_wall_distance(origin, dirs, section, profile)
    hit = origin + s[:, None] * dirs
    ok = np.isfinite(s)
    assert ok.mean() > 0.99 and np.all(s[ok] > 0)
    theta = np.arctan2(hit[ok, 1], hit[ok, 0])
    wall = section.radius_at(theta) * profile.at(hit[ok, 2])
    assert np.max(np.abs(np.hypot(hit[ok, 0], hit[ok, 1]) - wall)) < 1e-9
    flat = RadiusProfile(np.array([0.0]), np.array([1.0]))
    np.testing.assert_array_equal(ray_wall_distance(origin, dirs, section, flat),
                                  ray_wall_distance(origin, dirs, section))


def test_rays_meet_the_first_wall_where_it_widens() -> None:
    # a step out to 1.3 times the radius between z 20 and 22 mm: a ray from z 0 that
    # reaches the narrow wall before the step meets it there, not the wide wall beyond
    section = PipeSection.circle(65.0)
    profile = RadiusProfile(np.array([20.0, 22.0]), np.array([1.0, 1.3]))
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(5000, 3))
    dirs[:, 2] = np.abs(dirs[:, 2])
    origin = np.array([2.0, 1.0, 0.0])
    s = ray_wall_distance(origin, dirs, section, profile)
    # the first crossing by a fine march along each ray
    steps = np.linspace(0.0, 200.0, 200001)[:, None]
    for k in range(0, 5000, 250):
        p = origin + steps * dirs[k] / np.linalg.norm(dirs[k])
        out = np.hypot(p[:, 0], p[:, 1]) >= 32.5 * profile.at(p[:, 2])
        first = steps[np.argmax(out), 0] / np.linalg.norm(dirs[k])
        assert s[k] == pytest.approx(first, abs=2e-3 / np.linalg.norm(dirs[k]))


@pytest.mark.parametrize("z, scale", [([0.0, 0.0], [1.0, 1.0]), ([0.0, 1.0], [1.0, 0.0]),
                                      ([0.0, 1.0], [1.0]), ([1.0, 0.0], [1.0, 1.0])])
def test_a_radius_profile_refuses_what_is_no_wall(z, scale) -> None:
    with pytest.raises(ValueError, match="RadiusProfile"):
        RadiusProfile(np.array(z), np.array(scale))


@settings(max_examples=40, deadline=None)
@given(angle=st.floats(-7.0, 7.0))
def test_rotations_of_one_angle_match_the_array_path_and_the_closed_form(angle) -> None:
    """A scalar angle takes the written-out path; an array of angles the vectorised
    one: the same matrices, and the textbook ones."""
    c, s = np.cos(angle), np.sin(angle)
    closed = {rot_x: [[1, 0, 0], [0, c, -s], [0, s, c]],
              rot_y: [[c, 0, s], [0, 1, 0], [-s, 0, c]],
              rot_z: [[c, -s, 0], [s, c, 0], [0, 0, 1]]}
    for rot, matrix in closed.items():
        one = rot(angle)
        assert one.shape == (3, 3) and one.dtype == np.float64
        np.testing.assert_allclose(one, rot(np.array([angle, 0.0]))[0], rtol=0, atol=1e-15)
        np.testing.assert_allclose(one, matrix, rtol=0, atol=1e-15)
