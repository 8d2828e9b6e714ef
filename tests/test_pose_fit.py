"""Pose from the ring: exact closed form, full round trips, both hypotheses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipestitch.camera import OpenCVFisheyeModel, default_camera
from pipestitch.geometry import PipeSection, Pose, laser_ring
from pipestitch.pose_fit import ConicModel, LaserPlane, fit_pose, model_conic, pose_from_conic
from pipestitch.ring import RingDetection, detect_ring
from pipestitch.simulate.render import Optics, Renderer, WallTexture

D = 16.0


def as_vec(p: Pose) -> np.ndarray:
    return np.array([np.rad2deg(p.alpha), np.rad2deg(p.beta), p.dx_mm, p.dy_mm])


@settings(max_examples=80, deadline=None)
@given(a=st.floats(-0.25, 0.25), b=st.floats(-0.25, 0.25), dx=st.floats(-8, 8),
       dy=st.floats(-8, 8), diameter=st.sampled_from([50.0, 65.0, 80.0]))
def test_closed_form_recovers_pose_and_its_mirror(a, b, dx, dy, diameter) -> None:
    pose = Pose(a, b, dx, dy)
    ring = laser_ring(pose, PipeSection.circle(diameter), D, n_points=60)
    conic = ConicModel.from_estimate(ring[:, :2])
    assert conic is not None
    sols = pose_from_conic(*conic.normalised(), D)
    assert len(sols) == 2
    errs = [np.abs(as_vec(p) - as_vec(pose)).max() for p, _ in sols]
    # Tilt enters the conic quadratically (axis ratio 1/cos), so rounding errors of
    # 1e-16 in the conic become sqrt(1e-16) = 1e-8 rad near zero tilt, and 1e-8 rad
    # times d = 16 mm in the offset: bounds of 1e-5 (deg and mm) cover that.
    assert min(errs) < 1e-5
    for p, r in sols:
        assert r == pytest.approx(diameter / 2, abs=1e-7)
        # Both hypotheses put the ring exactly on the wall: that is the ambiguity.
        w = p.to_world(ring)
        np.testing.assert_allclose(np.hypot(w[:, 0], w[:, 1]), diameter / 2, atol=1e-6)
    mirror = sols[int(np.argmax(errs))][0]
    # The mirror is exactly (-alpha, -beta) with another offset.
    assert mirror.alpha == pytest.approx(-a, abs=1e-7)
    assert mirror.beta == pytest.approx(-b, abs=1e-7)


TILTED = np.array([np.sin(np.deg2rad(1.0)) * np.cos(0.7), np.sin(np.deg2rad(1.0)) * np.sin(0.7),
                   np.cos(np.deg2rad(1.0))])   # a laser plane misaligned by 1°


@settings(max_examples=40, deadline=None)
@given(a=st.floats(-0.2, 0.2), b=st.floats(-0.2, 0.2), dx=st.floats(-6, 6), dy=st.floats(-6, 6))
def test_closed_form_with_a_tilted_laser_plane(a, b, dx, dy) -> None:
    pose = Pose(a, b, dx, dy)
    ring = laser_ring(pose, PipeSection.circle(65.0), D, n_points=60, plane_normal=TILTED)
    uv = LaserPlane.of(D, TILTED)
    conic = ConicModel.from_estimate((ring - D * uv.normal) @ uv.basis.T)
    sols = pose_from_conic(*conic.normalised(), D, TILTED)
    errs = [np.abs(as_vec(p) - as_vec(pose)).max() for p, _ in sols]
    assert min(errs) < 1e-5
    for p, r in sols:   # both put the ring on the wall, and the model conic maps back
        assert r == pytest.approx(32.5, abs=1e-7)
        w = p.to_world(ring)
        np.testing.assert_allclose(np.hypot(w[:, 0], w[:, 1]), 32.5, atol=1e-6)
        again = pose_from_conic(*model_conic(p, r, uv), D, TILTED)
        assert min(np.abs(as_vec(q) - as_vec(p)).max() for q, _ in again) < 1e-5


def test_calibrated_plane_normal_removes_the_pose_bias() -> None:
    """A 1° plane misalignment left out biases the pose; given the normal, it does not."""
    pose = Pose.from_degrees(3.0, -2.0, 2.0, -1.0)
    cam, laser, led = _render(pose, plane_normal=TILTED)
    det = detect_ring(laser, cam, reflectance=led)

    def tilt_error(fit) -> float:
        return min(np.abs(as_vec(h.pose) - as_vec(pose))[:2].max() for h in fit.hypotheses)

    ignored = fit_pose(det, cam, D, plane_normal=None)
    calibrated = fit_pose(det, cam, D, plane_normal=TILTED)
    assert tilt_error(ignored) > 0.5       # about the 1° misalignment
    assert tilt_error(calibrated) < 0.15   # the round-trip accuracy of an aligned plane


def _render(pose: Pose, size: str = "half", optics: Optics | None = None,
            diameter: float = 65.0, plane_normal: np.ndarray | None = None):
    rng = np.random.default_rng(0)
    base = rng.uniform(0.6, 0.75, (36, 40)).astype(np.float32)
    albedo = np.kron(base, np.ones((100, 60), np.float32))
    r = Renderer(default_camera(size), PipeSection.circle(diameter),
                 WallTexture(albedo, 0.1, 0.1, -50.0), D, optics, plane_normal=plane_normal)
    laser, led = r.render_pair(pose, np.random.default_rng(3))
    return r.camera, laser, led


@pytest.mark.parametrize("pose", [Pose.from_degrees(4.0, -3.0, 5.0, -2.0),
                                  Pose.from_degrees(-12.0, 7.0, -9.0, 6.0),
                                  Pose.from_degrees(2.0, 2.0, 0.0, 0.0)])
def test_render_extract_solve_round_trip(pose: Pose) -> None:
    cam, laser, led = _render(pose)
    fit = fit_pose(detect_ring(laser, cam, reflectance=led), cam, D)
    assert fit.ok and len(fit.hypotheses) == 2
    err = min((np.abs(as_vec(h.pose) - as_vec(pose)) for h in fit.hypotheses),
              key=lambda e: e.max())
    # Half size, default noise: well inside the 0.5°/0.5 mm success tolerance.
    assert err[:2].max() < 0.15 and err[2:].max() < 0.05
    h0, h1 = fit.hypotheses
    assert h0.cost == pytest.approx(h1.cost, rel=0.05)
    assert h0.radius_mm == pytest.approx(32.5, abs=0.02)
    assert 0.02 < h0.rms_px < 0.5 and 0.001 < h0.rms_mm < 0.1
    best = min(fit.hypotheses, key=lambda h: np.abs(as_vec(h.pose) - as_vec(pose)).max())
    # The reported uncertainty is honest: the error is within 5 sigma.
    assert abs(np.rad2deg(best.pose.alpha - pose.alpha)) < 5 * np.rad2deg(best.std["alpha"])


def test_partial_ring_colour_glints_still_solve() -> None:
    pose = Pose.from_degrees(5.0, 3.0, -4.0, 2.0)
    optics = Optics(bit_depth=16, colour=True, glints=4, partial_ring_deg=60.0,
                    full_well_e=3000.0, read_noise=3.0 / 255, laser_peak=0.35)
    cam, laser, led = _render(pose, optics=optics)
    fit = fit_pose(detect_ring(laser, cam, reflectance=led), cam, D)
    assert fit.ok and 0.7 < fit.coverage < 0.86
    err = min((np.abs(as_vec(h.pose) - as_vec(pose)) for h in fit.hypotheses),
              key=lambda e: e.max())
    assert err[:2].max() < 0.5 and err[2:].max() < 0.2


def test_fixed_radius_and_no_ring() -> None:
    pose = Pose.from_degrees(4.0, -3.0, 5.0, -2.0)
    cam, laser, _ = _render(pose)
    fit = fit_pose(detect_ring(laser, cam), cam, D, fit_radius=False, nominal_radius_mm=32.5)
    assert fit.ok and all(h.radius_mm == 32.5 for h in fit.hypotheses)
    empty = RingDetection(np.zeros((0, 2)), np.zeros(0, int), np.zeros(0, int), np.zeros(0),
                          1440, 0.01)
    result = fit_pose(empty, cam, D)
    assert not result.ok and "ring not found" in result.reason
    with pytest.raises(ValueError, match="nominal_radius_mm"):
        fit_pose(empty, cam, D, fit_radius=False)


def test_noise_free_accuracy_full_size() -> None:
    pose = Pose.from_degrees(-8.0, 6.0, 3.0, -7.0)
    optics = Optics(full_well_e=1e12, read_noise=0.0, speckle=0.0)
    cam, laser, led = _render(pose, size="full", optics=optics)
    fit = fit_pose(detect_ring(laser, cam, reflectance=led), cam, D)
    err = min((np.abs(as_vec(h.pose) - as_vec(pose)) for h in fit.hypotheses),
              key=lambda e: e.max())
    # Issue target without noise: mean |error| <= 0.02° / 0.01 mm.
    assert err[:2].max() < 0.02 and err[2:].max() < 0.01


def test_opencv_fisheye_camera_end_to_end() -> None:
    # A 185° equidistant-like lens in OpenCV's model (theta_d = theta (1 + k1 theta^2 ...)).
    cam = OpenCVFisheyeModel(310.0, 310.0, 611.5, 511.5, (-0.01, 0.002, 0.0, 0.0), 1224, 1024)
    rng = np.random.default_rng(0)
    base = rng.uniform(0.6, 0.75, (36, 40)).astype(np.float32)
    albedo = np.kron(base, np.ones((100, 60), np.float32))
    r = Renderer(cam, PipeSection.circle(80.0), WallTexture(albedo, 0.1, 0.1, -50.0), D)
    pose = Pose.from_degrees(-5.0, 4.0, 6.0, 3.0)
    laser, led = r.render_pair(pose, np.random.default_rng(4))
    fit = fit_pose(detect_ring(laser, cam, reflectance=led), cam, D)
    assert fit.ok
    err = min((np.abs(as_vec(h.pose) - as_vec(pose)) for h in fit.hypotheses),
              key=lambda e: e.max())
    assert err[:2].max() < 0.15 and err[2:].max() < 0.05
    assert fit.hypotheses[0].radius_mm == pytest.approx(40.0, abs=0.03)


def test_first_order_px_rms_matches_projecting_the_model() -> None:
    """rms_px to first order (residual moved along its ray in the plane, turned into
    pixels with the local pixel -> plane Jacobian) against projecting the model ring
    at each point's plane angle, the exact definition."""
    from pipestitch.pose_fit import LaserPlane, plane_points, ring_rms_px

    pose = Pose.from_degrees(4.0, -3.0, 5.0, -2.0)
    cam, laser, led = _render(pose)
    fit = fit_pose(detect_ring(laser, cam, reflectance=led), cam, D)
    h = fit.hypotheses[0]
    pixels = fit.ring.pixels.astype(np.float64)[::6]          # <= 128 points: all used
    uv, valid = plane_points(pixels, cam, D)
    assert valid.all() and len(uv) <= 128
    plane = LaserPlane.of(D)
    rot = h.pose.rotation_world_probe()
    world = plane.to_probe(uv) @ rot[:2].T + [h.pose.dx_mm, h.pose.dy_mm]
    resid = np.hypot(world[:, 0], world[:, 1]) - h.radius_mm
    approx = ring_rms_px(h.pose, h.radius_mm, pixels, uv, resid, cam, plane)
    model = cam.project(laser_ring(h.pose, PipeSection(h.radius_mm), D,
                                   phi=np.arctan2(uv[:, 1], uv[:, 0])))
    exact = float(np.sqrt(np.mean(np.sum((model - pixels) ** 2, axis=1))))
    assert 0.02 < exact < 0.5
    assert approx == pytest.approx(exact, rel=0.005)   # measured: 0.02 % apart
