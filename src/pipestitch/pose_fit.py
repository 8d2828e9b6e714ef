"""Ring points -> probe pose hypotheses (both mirror solutions, always).

Ring pixels are unprojected to rays and intersected with the known laser plane
z = d, which gives exact 3-D points: no iteration over the pose is needed to get
them. In the plane the ring is a conic, q(u) = A u + c on the wall |q| = r, with
A the top-left 2 × 2 block of R = Rx(alpha)·Ry(beta) and c the plane centre's
world offset. Because R is a rotation, A^T A = I - w w^T with
w = (-cos(alpha) sin(beta), sin(alpha)) the pipe axis seen from the probe. An
ellipse fitted to the plane points therefore gives |w| (from its axis ratio), the
direction of w up to sign (its minor axis), the radius and the offset: a closed
form for both hypotheses, w and -w, which are exactly the mirror ambiguity
(alpha, beta) <-> (-alpha, -beta) with another offset. Both are then refined by
robust least squares (``scipy.optimize.least_squares``, soft-L1 loss, analytic
Jacobian) of the radial distance of every plane point from the wall, in mm.

Outliers (glints, reflections, second candidates on a ray) are removed by RANSAC
on the ellipse (``skimage.measure.ransac``) when the strongest candidates do not
already agree, then by re-selecting one candidate per ray by its distance from the
conic until the set is stable. This module fits one frame; choosing between the
hypotheses over a run is :mod:`pipestitch.ambiguity`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from skimage.measure import ransac

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, plane_basis, rot_x, rot_y
from pipestitch.ring import RingDetection

__all__ = [
    "ConicModel",
    "Hypothesis",
    "LaserPlane",
    "PoseFit",
    "RingPoints",
    "fit_pose",
    "model_conic",
    "plane_points",
    "plane_to_world",
    "pose_from_conic",
    "ring_rms_px",
]

PARAMS = ("alpha", "beta", "dx_mm", "dy_mm", "radius_mm")


@dataclass(frozen=True)
class Hypothesis:
    """One pose solution of a frame.

    Attributes
    ----------
    pose : Pose
        alpha, beta, dx, dy (roll and z are 0: the ring cannot see them).
    radius_mm : float
        Local pipe radius from the ring.
    cost : float
        Robust least-squares cost at the solution (0.5 · sum of rho(residual²)).
    rms_mm, rms_px : float
        RMS residual of the inliers, on the wall (mm) and in the image (px).
    std : dict
        One-sigma uncertainty of each parameter (radians for angles, mm).
    information : numpy.ndarray or None
        4 x 4 information matrix (inverse covariance) of (alpha, beta, dx, dy) from the
        ring, the radius marginalised out: what the ring says about the pose, for fusing
        with other evidence (:mod:`pipestitch.refine`).
    """

    pose: Pose
    radius_mm: float
    cost: float
    rms_mm: float
    rms_px: float
    std: dict[str, float] = field(default_factory=dict)
    information: np.ndarray | None = field(default=None, compare=False)
    section: PipeSection | None = None

    @property
    def pipe_section(self) -> PipeSection:
        """The fitted cross-section: an oval when one was fitted, else the circle."""
        return self.section if self.section is not None else PipeSection(self.radius_mm)


@dataclass(frozen=True)
class RingPoints:
    """A frame's ring inliers, kept for later fits (subsampled to at most 720).

    ``uv`` are in-plane coordinates (mm), ``pixels`` the image points they came from.
    """

    uv: np.ndarray
    pixels: np.ndarray
    plane: LaserPlane

    @property
    def points_mm(self) -> np.ndarray:
        """(N, 3) probe-frame points on the laser plane (float64)."""
        return self.plane.to_probe(self.uv.astype(np.float64))


@dataclass(frozen=True)
class PoseFit:
    """Result of fitting one laser frame: both hypotheses or a reason why not.

    ``hypotheses[1]`` is the mirror of ``hypotheses[0]``; their order carries no
    preference. ``ok`` is False (with ``reason``) when no fit was possible.
    """

    ok: bool
    reason: str
    hypotheses: tuple[Hypothesis, ...] = ()
    n_points: int = 0
    coverage: float = 0.0
    model: str = "circle"
    ring: RingPoints | None = field(default=None, compare=False)


@dataclass(frozen=True)
class LaserPlane:
    """The laser plane n·p = d in the probe frame (SPEC: n = +z, i.e. z = d).

    ``basis`` holds two unit vectors spanning the plane
    (:func:`pipestitch.geometry.plane_basis`; probe x and y for SPEC's plane), so a
    plane point is d·n + u[0]·basis[0] + u[1]·basis[1].
    """

    distance_mm: float
    normal: np.ndarray
    basis: np.ndarray   # (2, 3): the in-plane unit vectors e1, e2

    @classmethod
    def of(cls, distance_mm: float, normal: np.ndarray | None = None) -> LaserPlane:
        """Plane at ``distance_mm`` with the given normal (default SPEC's +z)."""
        n = (0.0, 0.0, 1.0) if normal is None else tuple(float(v) for v in np.ravel(normal))
        return _laser_plane(float(distance_mm), n)

    def to_probe(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) in-plane coordinates -> (N, 3) probe-frame points, mm."""
        return self.distance_mm * self.normal + uv @ self.basis


@functools.lru_cache(maxsize=64)
def _laser_plane(distance_mm: float, normal: tuple[float, ...]) -> LaserPlane:
    n = np.asarray(normal) / np.linalg.norm(normal)
    plane = LaserPlane(distance_mm, n, np.array(plane_basis(n)))
    plane.normal.flags.writeable = plane.basis.flags.writeable = False  # shared: read-only
    return plane


def plane_points(pixels: np.ndarray, camera: CameraModel, plane_distance_mm: float,
                 plane_normal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the rays of ring pixels with the laser plane n·p = d.

    Returns
    -------
    points : numpy.ndarray, shape (M, 2)
        In-plane coordinates, mm (probe x, y for SPEC's plane z = d).
    valid : numpy.ndarray of bool, shape (N,)
        Which pixels gave a point (ray in front of the plane, inside the lens).
    """
    plane = LaserPlane.of(plane_distance_mm, plane_normal)
    rays = camera.unproject(pixels)
    if plane.normal[2] == 1.0:  # SPEC's plane z = d: the basis is probe x, y
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = plane_distance_mm / rays[:, 2]
        valid = np.isfinite(scale) & (rays[:, 2] > 1e-6)
        return rays[valid, :2] * scale[valid, None], valid
    along = rays @ plane.normal
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = plane.distance_mm / along
    valid = np.isfinite(scale) & (along > 1e-6)
    return (rays[valid] * scale[valid, None]) @ plane.basis.T, valid


class ConicModel:
    """General conic a x² + b xy + c y² + d x + e y + f = 0 for ``skimage.measure.ransac``.

    Written here rather than using ``skimage.measure.EllipseModel`` because that
    model's residuals are iterative per-point geometric distances: over hundreds of
    RANSAC trials and thousands of candidates that costs seconds per frame. This is
    the algebraic fit (SVD, on coordinates normalised to unit scale) with the
    first-order (Sampson) distance as residual, which is accurate to well under the
    inlier threshold near the curve.
    """

    def __init__(self) -> None:
        self.coef = np.zeros(6)
        self.scale = 1.0

    @classmethod
    def from_estimate(cls, data: np.ndarray) -> ConicModel | None:
        """A fitted model, or None when the points do not make an ellipse (skimage API)."""
        model = cls()
        return model if model.estimate(data) else None

    def estimate(self, data: np.ndarray) -> bool:
        """Fit the conic to (N >= 5, 2) points; False if it is not an ellipse."""
        scale = float(np.sqrt(np.mean(np.sum(data**2, axis=1)))) or 1.0
        x, y = data[:, 0] / scale, data[:, 1] / scale
        design = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
        # Smallest eigenvector of the 6 x 6 scatter: the SVD of the N x 6 design gives
        # the same vector on coordinates of unit scale, at several times the cost.
        coef = np.linalg.eigh(design.T @ design)[1][:, 0]
        if not 4 * coef[0] * coef[2] - coef[1] ** 2 > 0:
            return False  # not an ellipse: the model keeps its previous conic
        self.coef, self.scale = coef, scale
        return True

    def residuals(self, data: np.ndarray) -> np.ndarray:
        """Sampson distance of each point from the conic (data units)."""
        a, b, c, d, e, f = self.coef
        x, y = data[:, 0] / self.scale, data[:, 1] / self.scale
        val = a * x * x + b * x * y + c * y * y + d * x + e * y + f
        gx, gy = 2 * a * x + b * y + d, b * x + 2 * c * y + e
        return np.abs(val) / np.maximum(np.hypot(gx, gy), 1e-12) * self.scale

    def normalised(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(Q, lin, c0) in data units with u^T Q u + 2 lin^T u + c0 = 0, max eig(Q) = 1."""
        a, b, c, d, e, f = self.coef
        s = self.scale
        q = np.array([[a, b / 2], [b / 2, c]]) / s**2
        lin = np.array([d, e]) / (2 * s)
        lam = np.linalg.eigvalsh(q)
        norm = lam[-1] if lam[0] > 0 else lam[0]  # an ellipse has both eigenvalues of one sign
        return q / norm, lin / norm, float(f / norm)


def pose_from_conic(q: np.ndarray, lin: np.ndarray, c0: float, plane_distance_mm: float,
                    plane_normal: np.ndarray | None = None) -> list[tuple[Pose, float]]:
    """Closed-form poses (both mirrors) and radius from the ring's conic in the plane.

    Parameters
    ----------
    q, lin, c0 : conic u^T q u + 2 lin^T u + c0 = 0 in in-plane coordinates u
        (:func:`plane_points`), normalised so max eig(q) = 1.
    plane_distance_mm : float
        Laser plane distance d.
    plane_normal : numpy.ndarray, optional
        Plane normal in the probe frame (default SPEC's +z).

    Returns
    -------
    list of (Pose, radius_mm)
        Two entries, w and -w; empty if the conic is not an ellipse of this form.

    Notes
    -----
    With P the plane basis (3 x 2), a wall point's world (x, y) is A u + c with
    A = (R P)[:2]; A^T A = I - w w^T where w = P^T a and a = R^T e_z is the pipe
    axis in the probe frame. The conic's minor axis gives w up to sign, and
    a = P w + sqrt(1 - |w|²) n (the axis points forward, like the normal).
    """
    plane = LaserPlane.of(plane_distance_mm, plane_normal)
    basis = plane.basis
    evals, evecs = np.linalg.eigh(q)
    w_norm = np.sqrt(max(0.0, 1 - evals[0]))
    r2 = float(lin @ np.linalg.solve(q, lin) - c0)
    if r2 <= 0:
        return []
    out = []
    for sign in (1.0, -1.0):
        w = sign * w_norm * evecs[:, 0]
        axis = w @ basis + np.sqrt(max(0.0, 1 - w @ w)) * plane.normal
        alpha = np.arcsin(np.clip(axis[1], -1, 1))
        beta = np.arcsin(np.clip(-axis[0] / np.cos(alpha), -1, 1))
        rot = rot_x(alpha) @ rot_y(beta)
        centre = np.linalg.solve((rot[:2] @ basis.T).T, lin)
        t = centre - rot[:2] @ (plane.distance_mm * plane.normal)
        out.append((Pose(float(alpha), float(beta), float(t[0]), float(t[1])), float(np.sqrt(r2))))
    return out


def model_conic(pose: Pose, radius_mm: float, plane: LaserPlane) -> tuple[np.ndarray, np.ndarray,
                                                                          float]:
    """The ring conic (q, lin, c0) in plane coordinates that a pose and radius predict.

    Inverse of :func:`pose_from_conic`: both mirror poses give the same conic.
    """
    a_mat, c = plane_to_world(pose, plane)
    return a_mat.T @ a_mat, a_mat.T @ c, float(c @ c - radius_mm**2)


def plane_to_world(pose: Pose, plane: LaserPlane) -> tuple[np.ndarray, np.ndarray]:
    """(A, c): a plane point u (in-plane coordinates) lies at world (x, y) = A u + c."""
    rot = rot_x(pose.alpha) @ rot_y(pose.beta)
    return (rot[:2] @ plane.basis.T,
            rot[:2] @ (plane.distance_mm * plane.normal) + np.array([pose.dx_mm, pose.dy_mm]))


def _rotation_rows(x: np.ndarray) -> np.ndarray:
    """(6, 3): rows 0-1 of R = Rx(alpha)·Ry(beta), then of dR/dalpha, then of dR/dbeta."""
    a, b = x[0], x[1]
    rx, ry = rot_x(a), rot_y(b)
    drx = np.array([[0, 0, 0], [0, -np.sin(a), -np.cos(a)], [0, np.cos(a), -np.sin(a)]])
    dry = np.array([[-np.sin(b), 0, np.cos(b)], [0, 0, 0], [-np.cos(b), 0, -np.sin(b)]])
    return np.vstack([(rx @ ry)[:2], (drx @ ry)[:2], (rx @ dry)[:2]])


def _residuals_jacobian(x: np.ndarray, p3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_residuals` and its analytic Jacobian in (alpha, beta, dx, dy, r)."""
    prod = p3 @ _rotation_rows(x).T
    q = prod[:, :2] + x[2:4]
    rho = np.hypot(q[:, 0], q[:, 1])
    n = q / rho[:, None]
    jac = np.empty((len(p3), 5))
    jac[:, 0] = n[:, 0] * prod[:, 2] + n[:, 1] * prod[:, 3]
    jac[:, 1] = n[:, 0] * prod[:, 4] + n[:, 1] * prod[:, 5]
    jac[:, 2:4] = n
    jac[:, 4] = -1.0
    return rho - x[4], jac


def _soft_l1(resid: np.ndarray, f_scale: float) -> tuple[float, np.ndarray]:
    """Soft-L1 cost 0.5 f² Σ 2(√(1 + (r/f)²) − 1) (scipy's definition) and IRLS weights."""
    root = np.sqrt(1 + (resid / f_scale) ** 2)
    return float(f_scale**2 * np.sum(root - 1)), 1 / root


def _refine(pose: Pose, radius: float, p3: np.ndarray, fit_radius: bool,
            f_scale: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Robust (soft-L1) least squares of the radial residuals from a close start.

    Hand-written damped Gauss-Newton on iteratively reweighted normal equations
    rather than ``scipy.optimize.least_squares``: the problem has 4-5 parameters and
    an analytic Jacobian, and scipy's per-call set-up alone cost ~3 ms per
    hypothesis (measured), 20× the arithmetic here. The loss and cost are scipy's
    soft-L1. The closed-form start is within a few thousandths of a degree, so two
    or three iterations reach a step far below the noise.
    """
    x = np.array([pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm, radius])
    return _gauss_newton(x, p3, 5 if fit_radius else 4, f_scale)


def _gauss_newton(x: np.ndarray, p3: np.ndarray, n_free: int, f_scale: float,
                  max_iter: int = 30) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Damped IRLS Gauss-Newton; stops once a step is below 2 % of every parameter's sigma."""
    resid, jac = _residuals_jacobian(x, p3)
    cost, weight = _soft_l1(resid, f_scale)
    damping = 1e-9
    dof = max(1, len(p3) - n_free)
    for _ in range(max_iter):
        jw = jac[:, :n_free] * weight[:, None]
        normal = jw.T @ jac[:, :n_free]
        step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), -(jw.T @ resid))
        # sigma of each parameter (weighted normal equations, residual variance)
        sigma2 = np.diag(np.linalg.inv(normal)) * max(float(weight @ resid**2) / dof, 1e-12)
        trial = x.copy()
        trial[:n_free] += step
        trial_resid, trial_jac = _residuals_jacobian(trial, p3)
        trial_cost, trial_weight = _soft_l1(trial_resid, f_scale)
        if trial_cost <= cost:
            x, resid, jac, weight, cost = trial, trial_resid, trial_jac, trial_weight, trial_cost
            damping /= 10
            if np.all(step**2 <= 4e-4 * sigma2):
                break
        else:
            damping = max(damping * 10, 1e-6)
            if damping > 1e6:
                break
    return x, cost, resid, jac


def _uncertainty(jac: np.ndarray, residuals: np.ndarray,
                 fit_radius: bool) -> tuple[dict[str, float], np.ndarray | None]:
    """1-sigma of each parameter and the pose's 4 x 4 information matrix.

    From the plain (unweighted) Jacobian and residuals; with the radius fitted it is
    marginalised out of the information (Schur complement).
    """
    dof = max(1, len(residuals) - jac.shape[1])
    sigma2 = max(float(residuals @ residuals) / dof, 1e-12)
    info = jac.T @ jac / sigma2
    if fit_radius:
        pose_info = info[:4, :4] - np.outer(info[:4, 4], info[4, :4]) / max(info[4, 4], 1e-300)
    else:
        pose_info = info
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return {}, pose_info
    names = PARAMS if fit_radius else PARAMS[:4]
    return {n: float(np.sqrt(max(cov[i, i], 0))) for i, n in enumerate(names)}, pose_info


def _ransac_conic(pts: np.ndarray, threshold_mm: float,
                  rng: np.random.Generator) -> tuple[ConicModel | None, np.ndarray]:
    model, inliers = ransac(pts, ConicModel, min_samples=5, residual_threshold=threshold_mm,
                            max_trials=200, rng=rng)
    if model is None or inliers is None:
        return None, np.zeros(len(pts), bool)
    model.estimate(pts[inliers])  # final fit on all inliers
    return model, inliers


def fit_pose(detection: RingDetection, camera: CameraModel, plane_distance_mm: float, *,
             nominal_radius_mm: float | None = None, fit_radius: bool = True,
             min_coverage: float = 0.25, noise_mm: float = 0.05,
             plane_normal: np.ndarray | None = None, seed: int = 0) -> PoseFit:
    """Fit both pose hypotheses to one frame's ring candidates.

    Parameters
    ----------
    detection : RingDetection
        Ring candidates (:func:`pipestitch.ring.detect_ring`).
    camera : CameraModel
        Camera model.
    plane_distance_mm : float
        Laser plane distance d.
    nominal_radius_mm : float, optional
        Pipe radius to use when ``fit_radius`` is False.
    fit_radius : bool
        Estimate the local pipe radius (default) or hold it at the nominal value.
    min_coverage : float
        Minimum fraction of azimuths with an inlier for a fit to be accepted.
    noise_mm : float
        Expected point noise on the wall; sets the robust loss scale.
    plane_normal : numpy.ndarray, optional
        Calibrated laser-plane normal in the probe frame (default SPEC's +z).
    seed : int
        Seed of the RANSAC sampler (results are deterministic).

    Returns
    -------
    PoseFit
        ``ok`` False with a reason when the frame has no usable ring.
    """
    if not fit_radius and nominal_radius_mm is None:
        raise ValueError("fit_pose: nominal_radius_mm is needed when fit_radius is False")
    if detection.pixels.shape[0] < 12 or detection.coverage < min_coverage:
        return PoseFit(False, f"ring not found (coverage {detection.coverage:.0%})",
                       coverage=detection.coverage)
    plane = LaserPlane.of(plane_distance_mm, plane_normal)
    pts, valid = plane_points(detection.pixels, camera, plane_distance_mm, plane.normal)
    azimuth, pixels = detection.azimuth[valid], detection.pixels[valid]
    threshold = max(0.3, 6 * noise_mm)
    conic, inliers = _initial_inliers(pts, detection.rank[valid], threshold, seed)
    if conic is None or inliers.sum() < 12:
        return PoseFit(False, "no ellipse found among ring candidates", coverage=detection.coverage)
    keep = inliers
    for _ in range(4):
        # Re-select inliers among all candidates, one per ray, until the set is
        # stable (the start may have missed a stretch of the ring). The conic's
        # Sampson distance is accurate to microns near the curve, so this needs no
        # nonlinear fit.
        new_keep = _one_per_azimuth(conic.residuals(pts), azimuth, max(0.25, 5 * noise_mm))
        if np.array_equal(new_keep, keep) or new_keep.sum() < 12 or not conic.estimate(
                pts[new_keep]):
            break
        keep = new_keep
    starts = pose_from_conic(*conic.normalised(), plane_distance_mm, plane.normal)
    if not starts:
        return PoseFit(False, "ring is not the section of a cylinder", coverage=detection.coverage)
    coverage = np.count_nonzero(np.bincount(azimuth[keep])) / detection.n_azimuths
    if coverage < min_coverage:
        return PoseFit(False, f"too few ring points fit ({coverage:.0%} of the ring)",
                       coverage=coverage)
    step = max(1, -(-int(keep.sum()) // 720))   # <= 720 points, float32: <= 12 kB a frame
    ring = RingPoints(pts[keep][::step].astype(np.float32),
                      pixels[keep][::step].astype(np.float32), plane)
    try:
        hyps = _both_hypotheses(starts[0], pts[keep], pixels[keep], camera, plane,
                                nominal_radius_mm, fit_radius, noise_mm)
    except np.linalg.LinAlgError:   # singular normal equations: the points span too little
        return PoseFit(False, "degenerate ring (the points do not determine a pose)",
                       coverage=coverage)
    return PoseFit(True, "", hyps, int(keep.sum()), float(coverage), "circle", ring)


def _both_hypotheses(start: tuple[Pose, float], uv: np.ndarray, pixels: np.ndarray,
                     camera: CameraModel, plane: LaserPlane, nominal_radius_mm: float | None,
                     fit_radius: bool, noise_mm: float) -> tuple[Hypothesis, Hypothesis]:
    """Refine one hypothesis; its mirror is the other pose of the refined conic.

    Both mirrors explain every plane point with the same residual (the same conic),
    so the optimum of one maps to the optimum of the other in closed form.
    """
    p3 = plane.to_probe(uv)
    radius0 = start[1] if fit_radius else float(nominal_radius_mm)
    x, cost, resid, jac = _refine(start[0], radius0, p3, fit_radius, noise_mm)
    pose, radius = Pose(*x[:4]), float(x[4])
    mirror = max(pose_from_conic(*model_conic(pose, radius, plane), plane.distance_mm,
                                 plane.normal) or [(pose, radius)],
                 key=lambda s: abs(s[0].alpha - pose.alpha) + abs(s[0].beta - pose.beta))[0]
    hyps = []
    for h in (pose, mirror):
        if hyps:
            resid, jac = _residuals_jacobian(np.array([h.alpha, h.beta, h.dx_mm, h.dy_mm, radius]),
                                             p3)
        std, info = _uncertainty(jac[:, :5 if fit_radius else 4], resid, fit_radius)
        if not hyps:  # the same curve in the image for both
            rms_px = ring_rms_px(h, radius, pixels, uv, resid, camera, plane)
        hyps.append(Hypothesis(h, radius, cost, float(np.sqrt(np.mean(resid**2))), rms_px, std,
                               info))
    return hyps[0], hyps[1]


def _initial_inliers(pts: np.ndarray, rank: np.ndarray, threshold: float,
                     seed: int) -> tuple[ConicModel | None, np.ndarray]:
    """A first conic and its inliers: directly when the strongest candidates agree.

    Most frames have few outliers: one algebraic fit of every ray's strongest
    candidate then explains 90 % of them and RANSAC is not needed.
    """
    strongest = rank == 0
    if strongest.sum() >= 12:
        conic = ConicModel.from_estimate(pts[strongest])
        if conic is not None:
            inliers = strongest & (conic.residuals(pts) < threshold)
            if inliers.sum() >= 0.9 * strongest.sum() and conic.estimate(pts[inliers]):
                return conic, inliers
    return _ransac_conic(pts, threshold, np.random.default_rng(seed))


def _one_per_azimuth(resid: np.ndarray, azimuth: np.ndarray, threshold: float) -> np.ndarray:
    """Mask keeping, per ray, the candidate closest to the model if within threshold."""
    if np.bincount(azimuth).max() <= 1:  # one candidate per ray: nothing to choose
        return resid < threshold
    order = np.lexsort((resid, azimuth))
    first = np.ones(order.size, bool)
    first[1:] = azimuth[order][1:] != azimuth[order][:-1]
    keep = np.zeros(resid.size, bool)
    best = order[first]
    keep[best[resid[best] < threshold]] = True
    return keep


def ring_rms_px(pose: Pose, radius: float, pixels: np.ndarray, uv: np.ndarray,
            resid_mm: np.ndarray, camera: CameraModel, plane: LaserPlane) -> float:
    """RMS image distance between observed points and the model ring at the same angle.

    To first order in the residual (tens of microns): a point's radial residual on the
    wall is moved back along its ray in the plane (direction u/|u| from the plane
    centre) and the plane offset is turned into pixels with the local pixel -> plane
    Jacobian (finite differences of the unprojection, one pixel apart). Projecting the
    model ring instead costs a lens-polynomial inversion per point.
    """
    sub = slice(None, None, max(1, len(uv) // 128))  # ~128 points estimate an RMS to ~6 %
    px, u, r = pixels[sub], uv[sub], resid_mm[sub]
    d_col = _plane_coords(px + [1.0, 0.0], camera, plane) - u
    d_row = _plane_coords(px + [0.0, 1.0], camera, plane) - u
    a_mat, c = plane_to_world(pose, plane)
    q = u @ a_mat.T + c
    n_w = q / np.linalg.norm(q, axis=1, keepdims=True)
    u_hat = u / np.linalg.norm(u, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        du = u_hat * (r / np.sum(n_w * (u_hat @ a_mat.T), axis=1))[:, None]
        jac = np.stack([d_col, d_row], axis=2)          # d(uv)/d(col, row)
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        dcol = (jac[:, 1, 1] * du[:, 0] - jac[:, 0, 1] * du[:, 1]) / det
        drow = (jac[:, 0, 0] * du[:, 1] - jac[:, 1, 0] * du[:, 0]) / det
    err2 = dcol**2 + drow**2
    return float(np.sqrt(np.nanmean(err2))) if np.any(np.isfinite(err2)) else float("nan")


def _plane_coords(pixels: np.ndarray, camera: CameraModel, plane: LaserPlane) -> np.ndarray:
    """In-plane coordinates of each pixel's ray, NaN where it misses the plane."""
    out = np.full((len(pixels), 2), np.nan)
    uv, valid = plane_points(pixels, camera, plane.distance_mm, plane.normal)
    out[valid] = uv
    return out
