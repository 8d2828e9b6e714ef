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

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from skimage.measure import ransac

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, laser_ring, rot_x, rot_y
from pipestitch.ring import RingDetection

__all__ = ["ConicModel", "Hypothesis", "PoseFit", "fit_pose", "plane_points", "pose_from_conic"]

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


def plane_points(pixels: np.ndarray, camera: CameraModel,
                 plane_distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the rays of ring pixels with the laser plane z = d.

    Returns
    -------
    points : numpy.ndarray, shape (M, 2)
        (x, y) in the plane, mm (probe frame).
    valid : numpy.ndarray of bool, shape (N,)
        Which pixels gave a point (ray in front of the plane, inside the lens).
    """
    rays = camera.unproject(pixels)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = plane_distance_mm / rays[:, 2]
    valid = np.isfinite(scale) & (rays[:, 2] > 1e-6)
    return rays[valid, :2] * scale[valid, None], valid


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
        coef = np.linalg.svd(design, full_matrices=False)[2][-1]
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


def pose_from_conic(q: np.ndarray, lin: np.ndarray, c0: float,
                    plane_distance_mm: float) -> list[tuple[Pose, float]]:
    """Closed-form poses (both mirrors) and radius from the ring's conic in the plane.

    Parameters
    ----------
    q, lin, c0 : conic u^T q u + 2 lin^T u + c0 = 0, normalised so max eig(q) = 1.
    plane_distance_mm : float
        Laser plane distance d.

    Returns
    -------
    list of (Pose, radius_mm)
        Two entries, w and -w; empty if the conic is not an ellipse of this form.
    """
    evals, evecs = np.linalg.eigh(q)
    w_norm = np.sqrt(max(0.0, 1 - evals[0]))
    out = []
    for sign in (1.0, -1.0):
        w = sign * w_norm * evecs[:, 0]
        alpha = np.arcsin(np.clip(w[1], -1, 1))
        beta = np.arcsin(np.clip(-w[0] / np.cos(alpha), -1, 1))
        rot = rot_x(alpha) @ rot_y(beta)
        centre = np.linalg.solve(rot[:2, :2].T, lin)
        r2 = float(lin @ np.linalg.solve(q, lin) - c0)
        if r2 <= 0:
            return []
        t = centre - rot[:2, 2] * plane_distance_mm
        out.append((Pose(float(alpha), float(beta), float(t[0]), float(t[1])), float(np.sqrt(r2))))
    return out


def _residuals(x: np.ndarray, pts: np.ndarray, d: float) -> np.ndarray:
    """Radial distance (mm) of plane points from the wall of radius x[4]."""
    q = _world_xy(x, pts, d)
    return np.hypot(q[:, 0], q[:, 1]) - x[4]


def _world_xy(x: np.ndarray, pts: np.ndarray, d: float) -> np.ndarray:
    rot = rot_x(x[0]) @ rot_y(x[1])
    return pts @ rot[:2, :2].T + rot[:2, 2] * d + x[2:4]


def _jacobian(x: np.ndarray, pts: np.ndarray, d: float) -> np.ndarray:
    """Analytic Jacobian of :func:`_residuals` with respect to (alpha, beta, dx, dy, r)."""
    a, b = x[0], x[1]
    p3 = np.column_stack([pts, np.full(len(pts), d)])
    rx, ry = rot_x(a), rot_y(b)
    drx = np.array([[0, 0, 0], [0, -np.sin(a), -np.cos(a)], [0, np.cos(a), -np.sin(a)]])
    dry = np.array([[-np.sin(b), 0, np.cos(b)], [0, 0, 0], [-np.cos(b), 0, -np.sin(b)]])
    q = _world_xy(x, pts, d)
    n = q / np.hypot(q[:, 0], q[:, 1])[:, None]
    dq_da = p3 @ (drx @ ry)[:2].T
    dq_db = p3 @ (rx @ dry)[:2].T
    return np.column_stack([np.sum(n * dq_da, 1), np.sum(n * dq_db, 1), n[:, 0], n[:, 1],
                            -np.ones(len(pts))])


def _refine(pose: Pose, radius: float, pts: np.ndarray, d: float, fit_radius: bool,
            f_scale: float) -> tuple[np.ndarray, float]:
    x0 = np.array([pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm, radius])
    free = slice(None) if fit_radius else slice(0, 4)

    def fun(v: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = v
        return _residuals(x, pts, d)

    def jac(v: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = v
        return _jacobian(x, pts, d)[:, free]

    res = least_squares(fun, x0[free], jac=jac, loss="soft_l1", f_scale=f_scale,
                        x_scale=np.array([0.01, 0.01, 1.0, 1.0, 1.0])[free], method="trf")
    x = x0.copy()
    x[free] = res.x
    return x, float(res.cost)


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
             seed: int = 0) -> PoseFit:
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
    pts, valid = plane_points(detection.pixels, camera, plane_distance_mm)
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
    starts = pose_from_conic(*conic.normalised(), plane_distance_mm)
    if not starts:
        return PoseFit(False, "ring is not the section of a cylinder", coverage=detection.coverage)
    radius0 = [r0 if fit_radius else float(nominal_radius_mm) for _, r0 in starts]
    coverage = np.unique(azimuth[keep]).size / detection.n_azimuths
    if coverage < min_coverage:
        return PoseFit(False, f"too few ring points fit ({coverage:.0%} of the ring)",
                       coverage=coverage)
    # Both mirrors are fitted to the same inliers: in the plane they explain them equally.
    hyps = []
    for (pose0, _), r0 in zip(starts, radius0, strict=True):
        x, cost = _refine(pose0, r0, pts[keep], plane_distance_mm, fit_radius, noise_mm)
        r = _residuals(x, pts[keep], plane_distance_mm)
        jac = _jacobian(x, pts[keep], plane_distance_mm)[:, :5 if fit_radius else 4]
        pose = Pose(*x[:4])
        std, info = _uncertainty(jac, r, fit_radius)
        hyps.append(Hypothesis(pose, float(x[4]), cost, float(np.sqrt(np.mean(r**2))),
                               _rms_px(pose, x[4], pixels[keep], pts[keep], camera,
                                       plane_distance_mm), std, info))
    return PoseFit(True, "", tuple(hyps), int(keep.sum()), float(coverage), "circle")


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
    order = np.lexsort((resid, azimuth))
    first = np.ones(order.size, bool)
    first[1:] = azimuth[order][1:] != azimuth[order][:-1]
    keep = np.zeros(resid.size, bool)
    best = order[first]
    keep[best[resid[best] < threshold]] = True
    return keep


def _rms_px(pose: Pose, radius: float, pixels: np.ndarray, pts: np.ndarray,
            camera: CameraModel, d: float) -> float:
    """RMS image distance between observed points and the model ring at the same angle."""
    step = max(1, len(pts) // 256)  # a few hundred points estimate an RMS well
    phi = np.arctan2(pts[::step, 1], pts[::step, 0])
    model = camera.project(laser_ring(pose, PipeSection(radius), d, phi=phi))
    err = np.linalg.norm(model - pixels[::step], axis=1)
    return float(np.sqrt(np.nanmean(err**2))) if np.any(np.isfinite(err)) else float("nan")
