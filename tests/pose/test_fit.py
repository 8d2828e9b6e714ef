"""Pose from the ring: exact closed form, full round trips, both hypotheses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipestitch.camera import OpenCVFisheyeModel, default_camera
from pipestitch.geometry import PipeSection, Pose, WallGrid, laser_ring
from pipestitch.pose._fit_kernels import (
    Plane,
    conic_through,
    lu,
    plain_pass,
    ransac_conic,
    solve_vector,
    sum_squares,
    sym_eig,
    wall_pass,
)
from pipestitch.pose.fit import (
    ConicModel,
    LaserPlane,
    fit_pose,
    model_conic,
    plane_points,
    pose_from_conic,
    ring_rms_px,
)
from pipestitch.pose.ring import RingDetection, detect_ring
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


def _texture(albedo: np.ndarray, diameter: float) -> WallTexture:
    """``albedo`` on a wall of ``diameter`` (mm): 0.1 deg and 0.1 mm per pixel, from
    z = -50 mm."""
    return WallTexture(albedo=albedo, grid=WallGrid(radius_mm=diameter / 2, deg_per_px=0.1,
                                                    mm_per_px_axial=0.1, z0_mm=-50.0,
                                                    n_cols=albedo.shape[1]))


def _render(pose: Pose, size: str = "half", optics: Optics | None = None,
            diameter: float = 65.0, plane_normal: np.ndarray | None = None):
    rng = np.random.default_rng(0)
    base = rng.uniform(0.6, 0.75, (36, 40)).astype(np.float32)
    albedo = np.kron(base, np.ones((100, 60), np.float32))
    r = Renderer(default_camera(size), PipeSection.circle(diameter),
                 _texture(albedo, diameter), D, optics, plane_normal=plane_normal)
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
    r = Renderer(cam, PipeSection.circle(80.0), _texture(albedo, 80.0), D)
    pose = Pose.from_degrees(-5.0, 4.0, 6.0, 3.0)
    laser, led = r.render_pair(pose, np.random.default_rng(4))
    fit = fit_pose(detect_ring(laser, cam, reflectance=led), cam, D)
    assert fit.ok
    err = min((np.abs(as_vec(h.pose) - as_vec(pose)) for h in fit.hypotheses),
              key=lambda e: e.max())
    # The reference lens's round-trip bounds: the same 1224 x 1024 sensor, default noise.
    assert err[:2].max() < 0.15 and err[2:].max() < 0.05
    assert fit.hypotheses[0].radius_mm == pytest.approx(40.0, abs=0.03)


class UnprojectOnly:
    """A camera model that offers ``unproject`` only (no compiled ``ray_kernel``)."""

    def __init__(self, camera) -> None:
        self.camera = camera

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        return self.camera.unproject(pixels)


@pytest.mark.parametrize("camera", ["ocam", "opencv"])
def test_fused_kernel_fits_as_the_unproject_path(camera: str) -> None:
    """A frame fitted in one compiled call (the camera's ray kernel inside) gives the
    same fit as unprojecting through ``unproject`` first; a model without a ray kernel
    still fits, and a ringless frame fails the same way on both paths."""
    cam = (default_camera("half") if camera == "ocam" else
           OpenCVFisheyeModel(310.0, 310.0, 611.5, 511.5, (-0.01, 0.002, 0.0, 0.0), 1224, 1024))
    rng = np.random.default_rng(3)
    base = rng.uniform(0.6, 0.75, (36, 40)).astype(np.float32)
    r = Renderer(cam, PipeSection.circle(65.0),
                 _texture(np.kron(base, np.ones((100, 60), np.float32)), 65.0), D)
    laser, led = r.render_pair(Pose.from_degrees(3.0, -2.0, 4.0, -3.0), np.random.default_rng(5))
    det = detect_ring(laser, cam, reflectance=led)
    fused, plain = fit_pose(det, cam, D), fit_pose(det, UnprojectOnly(cam), D)
    assert fused.ok and plain.ok and fused.n_points == plain.n_points > 100
    for a, b in zip(fused.hypotheses, plain.hypotheses, strict=True):
        np.testing.assert_allclose(as_vec(a.pose), as_vec(b.pose), rtol=0, atol=1e-12)
        assert (a.radius_mm, a.cost, a.rms_mm, a.rms_px) == pytest.approx(
            (b.radius_mm, b.cost, b.rms_mm, b.rms_px), rel=1e-12)
        assert a.std == pytest.approx(b.std, rel=1e-9)
    np.testing.assert_array_equal(fused.ring.uv, plain.ring.uv)
    empty = RingDetection(np.empty((0, 2)), np.empty(0, np.int64), np.empty(0, np.int64),
                          np.empty(0), 1440, 1.0)
    for model in (cam, UnprojectOnly(cam)):
        no_ring = fit_pose(empty, model, D)
        assert not no_ring.ok and no_ring.reason.startswith("ring not found")


def test_fits_alternating_lenses_and_settings_are_each_fitted_alone() -> None:
    """The fit's arguments that depend on the camera and the settings only are kept
    between frames (pose.fit._constant_arguments): fits alternating between two lenses,
    a held radius, a given noise and numpy-typed arguments are, to the bit, what each
    gives fitted alone."""
    from pipestitch.pose import fit as fit_module

    ocam = default_camera("half")
    opencv = OpenCVFisheyeModel(310.0, 310.0, 611.5, 511.5, (-0.01, 0.002, 0.0, 0.0), 1224,
                                1024)
    base = np.random.default_rng(3).uniform(0.6, 0.75, (36, 40)).astype(np.float32)
    texture = _texture(np.kron(base, np.ones((100, 60), np.float32)), 65.0)
    dets = {}
    for cam in (ocam, opencv):
        laser, led = Renderer(cam, PipeSection.circle(65.0), texture, D).render_pair(
            Pose.from_degrees(3.0, -2.0, 4.0, -3.0), np.random.default_rng(5))
        dets[id(cam)] = detect_ring(laser, cam, reflectance=led)
    calls = [(ocam, {}), (opencv, {}), (ocam, {"fit_radius": False, "nominal_radius_mm": 32.5}),
             (opencv, {"noise_mm": 0.05}), (ocam, {"min_coverage": 0.3})]

    def summary(fit) -> list:
        return [(as_vec(h.pose).tolist(), h.radius_mm, h.cost, h.std) for h in fit.hypotheses]

    alone = []
    for cam, kw in calls:
        fit_module._CONSTANT.clear()
        alone.append(summary(fit_pose(dets[id(cam)], cam, D, **kw)))
    fit_module._CONSTANT.clear()
    for k in range(2 * len(calls)):
        cam, kw = calls[k % len(calls)]
        typed = {key: np.float64(v) for key, v in kw.items() if isinstance(v, float)}
        fit = fit_pose(dets[id(cam)], cam, np.float64(D), **{**kw, **typed})
        assert fit.ok and summary(fit) == alone[k % len(calls)]
    assert len(fit_module._CONSTANT) == len(calls)


def test_first_order_px_rms_matches_projecting_the_model() -> None:
    """rms_px to first order (residual moved along its ray in the plane, turned into
    pixels with the local pixel -> plane Jacobian) against projecting the model ring
    at each point's plane angle, the exact definition."""
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


# --- the compiled kernels against plain references --------------------------------------

def _synthetic_detection(pose: Pose, diameter: float = 65.0, noise_px: float = 0.1,
                         plane_normal: np.ndarray | None = None, outliers: float = 0.0,
                         seed: int = 0) -> tuple[RingDetection, object]:
    """Ring pixels straight from the geometry (no rendering): one candidate per ray plus,
    on a share ``outliers`` of the rays, a stronger false one a few pixels off."""
    rng = np.random.default_rng(seed)
    cam = default_camera("full")
    ring = laser_ring(pose, PipeSection.circle(diameter), D, n_points=1440,
                      plane_normal=plane_normal)
    pixels = cam.project(ring) + rng.normal(0.0, noise_px, (1440, 2))
    azimuth, rank = np.arange(1440), np.zeros(1440, int)
    bad = np.flatnonzero(rng.random(1440) < outliers)
    false = pixels[bad] + rng.choice([-1.0, 1.0], (len(bad), 2)) * rng.uniform(3, 12, (len(bad), 2))
    rank[bad] = 1
    det = RingDetection(np.vstack([pixels, false]), np.r_[azimuth, bad], np.r_[rank, 0 * bad],
                        np.ones(1440 + len(bad)), 1440, 0.01)
    return det, cam


def _svd_conic(pts: np.ndarray) -> np.ndarray:
    """Reference algebraic conic: smallest right singular vector of the scaled design."""
    s = np.sqrt(np.mean(np.sum(pts**2, axis=1)))
    x, y = pts[:, 0] / s, pts[:, 1] / s
    coef = np.linalg.svd(np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)]))[2][-1]
    return coef * np.sign(coef[0])


def test_conic_fit_matches_the_svd_reference() -> None:
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 2 * np.pi, 400)
    pts = np.column_stack([3 + 31 * np.cos(t), -2 + 29 * np.sin(t)]) @ [[0.8, 0.6], [-0.6, 0.8]]
    pts += rng.normal(0, 0.05, pts.shape)
    model = ConicModel.from_estimate(pts)
    # the same unit vector by two solvers (Jacobi on the scatter, SVD of the design):
    # 1e-15 apart here; the bound leaves room for Jacobi's stopping test on harder
    # rings, and a wrong monomial or scaling would be off by order 1
    np.testing.assert_allclose(model.coef * np.sign(model.coef[0]), _svd_conic(pts), atol=1e-9)
    # the conic through five points is the same whether solved exactly or by the scatter
    # (1e-14 apart here: elimination with pivoting against an SVD of a 5 x 6 matrix)
    five = pts[:5]
    through = conic_through(five)
    assert through[2]
    np.testing.assert_allclose(through[0] * np.sign(through[0][0]), _svd_conic(five), atol=1e-8)
    assert np.abs(ConicModel.from_estimate(five).residuals(five)).max() < 1e-9


def test_ransac_kernel_finds_the_same_inliers_as_skimage() -> None:
    from skimage.measure import ransac

    rng = np.random.default_rng(2)
    t = rng.uniform(0, 2 * np.pi, 600)
    ring = np.column_stack([2 + 30 * np.cos(t), -1 + 28 * np.sin(t)]) + rng.normal(0, 0.02,
                                                                                 (600, 2))
    clutter = rng.uniform(-40, 40, (400, 2))
    clutter = clutter[ConicModel.from_estimate(ring).residuals(clutter) > 1.5][:300]
    pts = np.vstack([ring, clutter])
    truth = np.arange(len(pts)) < 600
    _, _, inliers, ok = ransac_conic(pts, np.random.default_rng(0).random((200, 5)), 0.3)
    reference = ransac(pts, ConicModel, min_samples=5, residual_threshold=0.3, max_trials=200,
                       rng=np.random.default_rng(0))[1]
    assert ok
    np.testing.assert_array_equal(inliers, truth)
    np.testing.assert_array_equal(reference, truth)


def _radial_residuals(x: np.ndarray, uv: np.ndarray, plane: LaserPlane) -> np.ndarray:
    """Reference residuals: world distance from the axis minus the radius (numpy)."""
    pose = Pose(*x[:4])
    world = pose.rotation_world_probe()[:2] @ plane.to_probe(uv).T
    return np.hypot(world[0] + x[2], world[1] + x[3]) - x[4]


@pytest.mark.parametrize("normal", [None, TILTED])
def test_wall_pass_matches_finite_differences(normal) -> None:
    plane = LaserPlane.of(D, normal)
    det, cam = _synthetic_detection(Pose.from_degrees(5.0, -4.0, 3.0, 2.0), plane_normal=normal)
    uv = plane_points(det.pixels, cam, D, normal)[0]
    x = np.array([np.deg2rad(5.1), np.deg2rad(-3.9), 3.05, 1.98, 32.4])
    resid, cost, _, jtwj, jtwr, jtj = wall_pass(x, uv[:, 0].copy(), uv[:, 1].copy(),
                                                Plane(D, plane.normal, plane.basis), 0.05)
    # the same residuals in another order of operations: 2e-14 apart here (mm)
    np.testing.assert_allclose(resid, _radial_residuals(x, uv, plane), atol=1e-12)
    jac = np.column_stack([(_radial_residuals(x + h, uv, plane)
                            - _radial_residuals(x - h, uv, plane)) / 2e-7
                           for h in np.eye(5) * 1e-7])
    weight = 1 / np.sqrt(1 + (resid / 0.05) ** 2)
    # the same sum, reassociated (the kernel's loop is vectorised): a few ulps
    assert cost == pytest.approx(0.05**2 * np.sum(np.sqrt(1 + (resid / 0.05) ** 2) - 1),
                                 rel=1e-12)
    # central differences, h = 1e-7 on ~30 mm points, carry ~1e-8 of rounding per entry:
    # the products agree to 6e-7 at most here; a wrong Jacobian term is off by order 1
    np.testing.assert_allclose(jtj, jac.T @ jac, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(jtwj, (jac * weight[:, None]).T @ jac, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(jtwr, (jac * weight[:, None]).T @ resid, rtol=1e-6, atol=1e-9)
    # the mirror's lean pass: the same residuals and unweighted J^T J (the same
    # arithmetic a point, summed in its own vectorised loop: a few ulps)
    plain_resid, plain_jtj = plain_pass(x, uv[:, 0].copy(), uv[:, 1].copy(),
                                        Plane(D, plane.normal, plane.basis))
    np.testing.assert_array_equal(plain_resid, resid)
    np.testing.assert_allclose(plain_jtj, jtj, rtol=1e-13, atol=1e-13 * np.abs(jtj).max())
    # the residuals' sum of squares, reassociated: a few ulps of numpy's
    assert sum_squares(resid) == pytest.approx(float(resid @ resid), rel=1e-13)


@pytest.mark.parametrize(("fit_radius", "normal"), [(True, None), (False, None), (True, TILTED)])
def test_fit_matches_scipy_least_squares(fit_radius: bool, normal) -> None:
    """The compiled IRLS Gauss-Newton against scipy's soft-L1 least squares, with the
    covariance against numpy's from the same Jacobian."""
    from scipy.optimize import least_squares

    pose = Pose.from_degrees(-6.0, 4.0, -5.0, 3.0)
    det, cam = _synthetic_detection(pose, noise_px=0.15, plane_normal=normal, outliers=0.05)
    fit = fit_pose(det, cam, D, nominal_radius_mm=32.4, fit_radius=fit_radius,
                   plane_normal=normal)
    assert fit.ok and fit.n_points >= 1400
    plane = LaserPlane.of(D, normal)
    uv = plane_points(det.pixels[:1440], cam, D, normal)[0]   # the true candidates
    h = fit.hypotheses[0]
    x = np.array([h.pose.alpha, h.pose.beta, h.pose.dx_mm, h.pose.dy_mm, h.radius_mm])
    n = 5 if fit_radius else 4

    def fun(p: np.ndarray) -> np.ndarray:
        return _radial_residuals(np.r_[p, x[4:]][:5], uv, plane)

    ref = least_squares(fun, x[:n] + [1e-3, -1e-3, 0.01, -0.01, 0.01][:n], loss="soft_l1",
                        f_scale=0.05, x_scale=[1e-3, 1e-3, 1e-2, 1e-2, 1e-2][:n], xtol=1e-12,
                        ftol=1e-12, gtol=1e-12)
    resid = fun(ref.x)   # ref.jac is scaled by the loss: the plain Jacobian by differences
    jac = np.column_stack([(fun(ref.x + h) - fun(ref.x - h)) / 2e-7 for h in np.eye(n) * 1e-7])
    cov = np.linalg.inv(jac.T @ jac / (resid @ resid / (len(resid) - n)))
    sigma = np.sqrt(np.diag(cov))
    # the optimum: within 5 % of a sigma (the iteration stops at steps below 2 %)
    assert np.all(np.abs(x[:n] - ref.x) < 0.05 * sigma)
    # ... which leaves the cost above scipy's optimum by (2 % sigma)² per parameter in
    # units of the residual variance: ~1e-6 of it
    assert ref.cost - 1e-9 < h.cost < ref.cost * (1 + 1e-5)
    std = np.array([h.std[k] for k in ("alpha", "beta", "dx_mm", "dy_mm", "radius_mm")[:n]])
    np.testing.assert_allclose(std, sigma, rtol=1e-3)
    assert h.rms_mm == pytest.approx(np.sqrt(np.mean(fun(x[:n]) ** 2)), rel=1e-9)
    # the mirror: the other pose of the same conic, its own uncertainty
    m = fit.hypotheses[1]
    assert np.abs(as_vec(m.pose) - as_vec(h.pose)).max() > 0.5
    for a, b in zip(model_conic(m.pose, m.radius_mm, plane), model_conic(h.pose, h.radius_mm,
                                                                          plane), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    assert m.cost == h.cost and m.rms_px == h.rms_px and m.std and m.information.shape == (4, 4)


@pytest.mark.parametrize("diameter", [50.0, 65.0, 80.0])
def test_synthetic_round_trip_both_hypotheses(diameter: float) -> None:
    rng = np.random.default_rng(int(diameter))
    for _ in range(6):
        r = diameter / 2
        lim = np.rad2deg(np.arcsin(2 * r / 145)) * 0.9
        pose = Pose.from_degrees(*rng.uniform(-lim, lim, 2), *rng.uniform(-0.5 * r, 0.5 * r, 2))
        det, cam = _synthetic_detection(pose, diameter, noise_px=0.0)
        fit = fit_pose(det, cam, D)
        assert fit.ok and len(fit.hypotheses) == 2
        errs = sorted(np.abs(as_vec(h.pose) - as_vec(pose)).max() for h in fit.hypotheses)
        assert errs[0] < 1e-6            # noise-free: exact
        mirror = max(fit.hypotheses, key=lambda h: np.abs(as_vec(h.pose) - as_vec(pose)).max())
        assert mirror.pose.alpha == pytest.approx(-pose.alpha, abs=1e-6)
        assert mirror.pose.beta == pytest.approx(-pose.beta, abs=1e-6)
        assert fit.hypotheses[0].radius_mm == pytest.approx(r, abs=1e-6)


def test_outliers_deterministic_and_rms_px_shared_with_ring_rms_px() -> None:
    pose = Pose.from_degrees(3.0, 7.0, 4.0, -6.0)
    det, cam = _synthetic_detection(pose, outliers=0.3, seed=5)
    fits = [fit_pose(det, cam, D, seed=s) for s in (0, 0, 1)]
    a, b, c = (f.hypotheses[0] for f in fits)
    assert a == b and np.array_equal(a.information, b.information)   # reproducible
    assert fits[0].n_points == 1440   # every true point back, every false one out
    assert np.abs(as_vec(a.pose) - as_vec(c.pose)).max() < 1e-9   # any seed finds the ring
    # the fit's px RMS (steps unprojected with the candidates) is ring_rms_px of its points
    clean, _ = _synthetic_detection(pose, seed=5)
    fit = fit_pose(clean, cam, D)
    h = fit.hypotheses[0]
    uv = plane_points(clean.pixels, cam, D)[0]
    plane = LaserPlane.of(D)
    resid = _radial_residuals(np.array([h.pose.alpha, h.pose.beta, h.pose.dx_mm, h.pose.dy_mm,
                                        h.radius_mm]), uv, plane)
    assert h.rms_px == pytest.approx(ring_rms_px(h.pose, h.radius_mm, clean.pixels, uv, resid,
                                                 cam, plane), rel=1e-9)


def test_small_linear_algebra_matches_numpy() -> None:
    rng = np.random.default_rng(3)
    for n in (2, 4, 5, 6):
        for cond in (10.0, 1e8, 1e14):
            q = np.linalg.qr(rng.normal(size=(n, n)))[0]
            lam = np.geomspace(1.0 / cond, 1.0, n) * rng.uniform(0.5, 2.0)
            a = (q * lam) @ q.T
            a = (a + a.T) / 2
            w, v = sym_eig(a)
            w_ref, v_ref = np.linalg.eigh(a)
            # two backward-stable solvers: eigenvalues within a few ulps of the largest
            np.testing.assert_allclose(w, w_ref, atol=1e-14 * lam.max())
            # each eigenvector up to sign, to the accuracy the gap allows (eps |a| / gap)
            for j in range(n):
                gap = np.min(np.abs(np.delete(w_ref, j) - w_ref[j]))
                assert min(np.abs(v[:, j] - v_ref[:, j]).max(),
                           np.abs(v[:, j] + v_ref[:, j]).max()) < 1e-13 * lam.max() / gap
            b = rng.normal(size=n)
            # a stable solve's residual grows with the condition: ~eps · cond, 10x margin
            np.testing.assert_allclose(a @ solve_vector(a, b), b, atol=1e-15 * cond * 10)
            assert lu(a)[2] == pytest.approx(np.linalg.det(a), rel=1e-8)
    with pytest.raises(np.linalg.LinAlgError):
        solve_vector(np.zeros((3, 3)), np.ones(3))


def test_plane_points_lie_on_the_tilted_plane() -> None:
    cam = default_camera("full")
    pixels = np.random.default_rng(4).uniform([200, 200], [2200, 1800], (500, 2))
    plane = LaserPlane.of(D, TILTED)
    uv, valid = plane_points(pixels, cam, D, TILTED)
    p = plane.to_probe(uv)
    np.testing.assert_allclose(p @ plane.normal, D, atol=1e-12)
    rays = cam.unproject(pixels[valid])        # and on each pixel's ray
    np.testing.assert_allclose(np.cross(p / np.linalg.norm(p, axis=1, keepdims=True), rays), 0,
                               atol=1e-12)
