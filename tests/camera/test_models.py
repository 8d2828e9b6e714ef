"""Camera models: round trips over the whole image circle, the optical axis, rays at
and beyond 90°, agreement with OpenCV and OCamCalib, and real calibrations."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipestitch.camera import OcamModel, OpenCVFisheyeModel, default_camera
from pipestitch.io.ocamcalib import read_calib_results

ROS_K = (290.050152, 289.392837, 399.938345, 273.885669)
ROS_D = (-0.030464, -0.019695, 0.002098, 0.001030)


def ros_camera() -> OpenCVFisheyeModel:
    fx, fy, cx, cy = ROS_K
    return OpenCVFisheyeModel(fx, fy, cx, cy, ROS_D, 800, 503)


def ray_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rays, accurate near zero (arccos of a dot product is not)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def pixels_in_circle(cam, max_theta: float, n: int, seed: int = 0) -> np.ndarray:
    """Random pixels whose rays lie within ``max_theta`` of the axis (the image circle)."""
    rng = np.random.default_rng(seed)
    theta = np.arccos(rng.uniform(np.cos(max_theta), 1.0, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    return cam.project(rays)


CAMERAS = {
    "default_full": lambda: default_camera("full"),
    "default_half": lambda: default_camera("half"),
    "ros_fisheye": ros_camera,
}


@pytest.mark.parametrize("name", CAMERAS)
def test_round_trip_whole_image_circle(name: str) -> None:
    cam = CAMERAS[name]()
    # Up to 95° off axis: past the 185° lens circle and past the 90° plane.
    px = pixels_in_circle(cam, np.deg2rad(95.0), 10_000)
    assert np.all(np.isfinite(px))
    back = cam.project(cam.unproject(px))
    # Required: < 1e-6 px. Both directions are exact (Newton), so float64 rounding remains.
    assert np.max(np.abs(back - px)) < 1e-6


@pytest.mark.parametrize("name", CAMERAS)
def test_unproject_gives_unit_rays_and_reprojects_angles(name: str) -> None:
    cam = CAMERAS[name]()
    rng = np.random.default_rng(1)
    theta = rng.uniform(0, np.deg2rad(95.0), 2000)
    phi = rng.uniform(0, 2 * np.pi, 2000)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    back = cam.unproject(cam.project(rays * rng.uniform(1, 500, (2000, 1))))
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), 1.0, atol=1e-12)
    assert np.max(ray_angle(back, rays)) < 1e-9  # radians


def test_ocam_optical_axis_and_ninety_degrees() -> None:
    cam = default_camera("full")
    col, row = cam.project(np.array([[0.0, 0.0, 5.0]]))[0]
    assert (col, row) == pytest.approx((cam.center_col, cam.center_row), abs=1e-12)
    np.testing.assert_allclose(cam.unproject(np.array([[cam.center_col, cam.center_row]]))[0],
                               [0, 0, 1], atol=1e-15)
    # At exactly 90° the ray lies in the image plane, so F(rho) = 0: the root of pol
    # computed independently with numpy.roots.
    roots = np.roots(cam.pol[::-1])
    rho90 = min(r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0)
    px = cam.project(np.array([[1.0, 0.0, 0.0]]))[0]  # +x probe = +column direction
    assert px[0] > cam.center_col + 900 and abs(px[1] - cam.center_row) < 2
    down = cam.project(np.array([[0.0, 1.0, 0.0]]))[0]  # +y probe = +row direction
    assert down[1] > cam.center_row + 900 and abs(down[0] - cam.center_col) < 2
    u = px[1] - cam.center_row
    v = px[0] - cam.center_col
    # Undo the affine part to get rho (the affine matrix is [[c, d], [e, 1]]).
    uu, vv = np.linalg.solve([[cam.c, cam.d], [cam.e, 1.0]], [u, v])
    assert np.hypot(uu, vv) == pytest.approx(rho90, abs=1e-6)


def test_rays_behind_the_image_plane_are_valid() -> None:
    cam = default_camera("full")
    rays = np.array([[np.sin(np.deg2rad(t)), 0.0, np.cos(np.deg2rad(t))] for t in (91, 92.5, 95)])
    px = cam.project(rays)
    assert np.all(np.isfinite(px))
    # Further off axis means further from the centre (no fold-back at 90°).
    assert np.all(np.diff(px[:, 0]) > 0)


def test_outside_valid_range_is_nan() -> None:
    cam = default_camera("half")
    assert np.all(np.isnan(cam.project(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]))))
    far = cam.unproject(np.array([[cam.center_col + 5000.0, cam.center_row]]))
    assert np.all(np.isnan(far))
    fish = ros_camera()
    assert np.all(np.isnan(fish.unproject(np.array([[1e5, 1e5]]))))


def test_ocam_projection_solves_its_lens_equation_for_points_in_any_order() -> None:
    cam = default_camera("half")
    rng = np.random.default_rng(5)
    # Unordered points over the whole field of view, at all distances.
    theta = rng.uniform(0, cam.max_incidence_rad, 20_000)
    phi = rng.uniform(0, 2 * np.pi, theta.size)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    px = cam.project(rays * rng.uniform(0.1, 1000, (theta.size, 1)))
    # rho from the pixel (affine undone) must satisfy theta = atan2(rho, -F(rho)).
    uv = np.linalg.solve([[cam.c, cam.d], [cam.e, 1.0]],
                         np.stack([px[:, 1] - cam.center_row, px[:, 0] - cam.center_col]))
    rho = np.hypot(*uv)
    lens = np.arctan2(rho, -np.polynomial.polynomial.polyval(rho, cam.pol))
    assert np.max(np.abs(lens - theta)) < 1e-12   # radians: float64 rounding
    bad = cam.project(np.array([[np.nan, 0.0, 1.0], [np.inf, 0.0, 1.0], [0.0, 0.0, np.nan]]))
    assert np.all(np.isnan(bad))


def test_bad_shapes_and_parameters_raise() -> None:
    cam = default_camera("half")
    with pytest.raises(ValueError, match=r"expected shape \(N, 3\)"):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"expected shape \(N, 2\)"):
        cam.unproject(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="finite"):
        OcamModel((-100.0, 0.0, float("nan")), (), 10, 10, 1, 0, 0, 20, 20)
    with pytest.raises(ValueError, match="negative"):
        OcamModel((100.0, 0.0, 1e-3), (), 10, 10, 1, 0, 0, 20, 20)
    with pytest.raises(ValueError, match="positive"):
        OpenCVFisheyeModel(-1.0, 1.0, 0, 0, (0, 0, 0, 0), 10, 10)


def test_opencv_model_matches_cv2_in_front_and_is_right_behind() -> None:
    cam = ros_camera()
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(500, 3))
    pts[:, 2] = np.abs(pts[:, 2]) + 0.05  # cv2 is valid in front of the image plane only
    ours = cam.project(pts)
    theirs, _ = cv2.fisheye.projectPoints(pts[None], np.zeros(3), np.zeros(3),
                                          cam.camera_matrix, np.array(ROS_D))
    np.testing.assert_allclose(ours, theirs[0], atol=1e-6)
    # Behind the image plane cv2 divides by a negative z: the point at 100° lands on the
    # opposite side of the centre, where 80° would be mirrored. Ours keeps it at 100°.
    behind = np.array([[np.sin(np.deg2rad(100)), 0.0, np.cos(np.deg2rad(100))]])
    mirror = np.array([[np.sin(np.deg2rad(80)), 0.0, np.cos(np.deg2rad(80))]])
    cv_behind, _ = cv2.fisheye.projectPoints(behind[None], np.zeros(3), np.zeros(3),
                                             cam.camera_matrix, np.array(ROS_D))
    assert cv_behind[0, 0, 0] == pytest.approx(2 * cam.cx - cam.project(mirror)[0, 0], abs=1e-6)
    assert cam.project(behind)[0, 0] > cam.project(mirror)[0, 0] + 10


def test_scaled_model_is_the_same_lens() -> None:
    full, half = default_camera("full"), default_camera("half")
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(1000, 3)) + [0, 0, 1.0]
    np.testing.assert_allclose(half.project(pts), (full.project(pts) + 0.5) * 0.5 - 0.5,
                               atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(theta=st.floats(0.0, np.deg2rad(92.5)), phi=st.floats(-np.pi, np.pi),
       dist=st.floats(1e-3, 1e4))
def test_round_trip_property_over_field_of_view(theta: float, phi: float, dist: float) -> None:
    cam = default_camera("full")
    ray = np.array([[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]])
    back = cam.unproject(cam.project(ray * dist))
    assert ray_angle(back, ray)[0] < 1e-9


# --- real calibrations ------------------------------------------------------------------

def test_komatsu_invpol_agrees_with_exact_inverse(shared_data) -> None:
    cam = read_calib_results(shared_data / "ocam_komatsu_fisheye_1600px" / "calib_results_0.txt")
    assert (cam.width, cam.height) == (1600, 1600)
    px = pixels_in_circle(cam, np.deg2rad(90.0), 5000, seed=4)
    rays = cam.unproject(px)
    assert np.max(np.abs(cam.project(rays) - px)) < 1e-6
    # OCamCalib's fitted invpol reproduces the exact inverse to its fit accuracy;
    # SOURCE.md measured <= 0.005 px for rho <= 800, so allow 0.01 px.
    assert np.max(np.abs(cam.project_invpol(rays) - px)) < 0.01


def test_backcam_reproduces_toolbox_reprojection_errors(shared_data) -> None:
    folder = shared_data / "ocam_urban_backcam_748x480"
    cam = read_calib_results(folder / "calib_results.txt")
    session = json.loads((folder / "Omni_Calib_Results_imgBack.json").read_text())
    xt, yt = np.asarray(session["board"]["Xt"]), np.asarray(session["board"]["Yt"])
    board = np.stack([xt, yt, np.ones_like(xt)], axis=1)
    for img in session["per_image"]:
        p_ocam = board @ np.asarray(img["RRfin"]).T  # OCamCalib frame: x rows, y cols, z back
        p_probe = np.stack([p_ocam[:, 1], p_ocam[:, 0], -p_ocam[:, 2]], axis=1)
        px = cam.project(p_probe)
        observed = np.stack([np.asarray(img["Yp_abs"]) - 1, np.asarray(img["Xp_abs"]) - 1], 1)
        err = np.linalg.norm(px - observed, axis=1)
        # The toolbox's own errMean used the same polynomial with a root solver: ours
        # must reproduce it to well under a thousandth of a pixel.
        assert err.mean() == pytest.approx(img["errMean_px"], abs=1e-3)


def test_real_opencv_fisheye_reprojects_its_corners(shared_data) -> None:
    folder = shared_data / "opencv_fisheye_ros_800x503"
    assert (folder / "ost.yaml").is_file()
    cam = ros_camera()
    px = pixels_in_circle(cam, np.deg2rad(89.0), 5000, seed=5)
    assert np.max(np.abs(cam.project(cam.unproject(px)) - px)) < 1e-6



# --- compiled unprojection against array-expression references -------------------------

def numpy_unproject_ocam(cam: OcamModel, px: np.ndarray) -> np.ndarray:
    """OCam unprojection as numpy array expressions (affine undone with linalg.solve)."""
    uv = np.linalg.solve([[cam.c, cam.d], [cam.e, 1.0]],
                         np.stack([px[:, 1] - cam.center_row, px[:, 0] - cam.center_col]))
    rho = np.hypot(*uv)
    rays = np.stack([uv[1], uv[0], -np.polynomial.polynomial.polyval(rho, cam.pol)], axis=1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rays[~(rho <= cam.max_rho_px)] = np.nan
    return rays


def numpy_unproject_fisheye(cam: OpenCVFisheyeModel, px: np.ndarray) -> np.ndarray:
    """OpenCV fisheye unprojection as numpy: theta_d(theta) inverted by bisection."""
    def distort(theta: np.ndarray) -> np.ndarray:
        k1, k2, k3, k4 = cam.k
        t2 = theta * theta
        return theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    yd = (px[:, 1] - cam.cy) / cam.fy
    xd = (px[:, 0] - cam.cx) / cam.fx - cam.skew * yd
    thetad = np.hypot(xd, yd)
    lo, hi = np.zeros_like(thetad), np.full_like(thetad, cam.max_incidence_rad)
    for _ in range(80):   # to float64 resolution, independently of the table and Newton
        mid = 0.5 * (lo + hi)
        above = distort(mid) > thetad
        lo, hi = np.where(above, lo, mid), np.where(above, mid, hi)
    theta, phi = 0.5 * (lo + hi), np.arctan2(yd, xd)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    rays[~(thetad <= distort(np.array(cam.max_incidence_rad)))] = np.nan
    return rays


@pytest.mark.parametrize("name", CAMERAS)
def test_compiled_unprojection_equals_numpy_reference(name: str) -> None:
    cam = CAMERAS[name]()
    reference = numpy_unproject_ocam if isinstance(cam, OcamModel) else numpy_unproject_fisheye
    rng = np.random.default_rng(6)
    # the whole image circle, the sensor (corners beyond the circle: NaN), the centre
    # and pixels that are not numbers
    px = np.concatenate([
        pixels_in_circle(cam, cam.max_incidence_rad * (1 - 1e-9), 20_000, seed=7),
        rng.uniform([-0.5 * cam.width, -0.5 * cam.height], [1.5 * cam.width, 1.5 * cam.height],
                    (5000, 2)),
        cam.project(np.array([[0.0, 0.0, 1.0]])),
        [[np.nan, 10.0], [10.0, np.inf]],
    ])
    with np.errstate(invalid="ignore"):   # inf · 0 in the reference's arithmetic
        ours, theirs = cam.unproject(px), reference(cam, px)
    assert np.array_equal(np.isnan(ours), np.isnan(theirs))
    assert np.isnan(ours).any(axis=1).sum() > 1000   # the test covers invalid pixels
    assert np.nanmax(np.abs(ours - theirs)) < 1e-12
    # and the same through any array layout or dtype the API accepts
    np.testing.assert_array_equal(cam.unproject(np.asfortranarray(px[:100]).astype(np.float32)),
                                  cam.unproject(px[:100].astype(np.float32).astype(np.float64)))


@pytest.mark.parametrize("name", CAMERAS)
def test_ray_kernel_gives_the_rays_of_unproject(name: str) -> None:
    """What compiled callers unproject through (``ray_kernel``) is ``unproject`` exactly."""
    from pipestitch.camera.kernels import rays_of

    cam = CAMERAS[name]()
    rng = np.random.default_rng(8)
    px = np.concatenate([pixels_in_circle(cam, cam.max_incidence_rad * 0.999, 3000, seed=9),
                         rng.uniform([-0.5 * cam.width, -0.5 * cam.height],
                                     [1.5 * cam.width, 1.5 * cam.height], (500, 2)),
                         [[np.nan, 10.0]]])
    ours = rays_of(cam.ray_kernel, np.ascontiguousarray(px))
    assert np.isnan(ours).any(axis=1).sum() > 50
    np.testing.assert_array_equal(ours, cam.unproject(px))
