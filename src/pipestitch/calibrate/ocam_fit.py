"""Scaramuzza (OCamCalib) camera model fitted to checkerboard views.

Scaramuzza's method (Scaramuzza, Martinelli, Siegwart, ICVS 2006; the OCamCalib
toolbox's ``calibrate.m``), written here because neither OpenCV nor any kept
library fits this model:

1. **Linear extrinsics** per view, for a trial distortion centre: a pixel's ray
   (u, v, f(ρ)) is parallel to the board point R·(X, Y, 0) + t, and the cross
   product's third component u·P2 − v·P1 = 0 does not involve f. It is linear in
   (r11, r12, r21, r22, t1, t2): the null vector of one small matrix per view;
   r31, r32 follow from orthonormality (two signs, both tried).
2. **Linear intrinsics**: the other two components are linear in the polynomial
   f(ρ) = a0 + a2 ρ² + … + aN ρᴺ (a1 = 0, as OCamCalib) and one t3 per view,
   shared over all views: one least-squares solve.
3. The distortion centre is searched on a coarse-to-fine grid (OCamCalib's
   ``findcenter``) by the reprojection error of that linear solution.
4. **Nonlinear refinement** (``scipy.optimize.least_squares``, sparse Jacobian):
   centre, affine c and d = e, polynomial and every view's pose minimise the
   reprojection error in pixels (the affine matrix's antisymmetric part is a
   rotation of the image about the centre, absorbed by the views' rolls, so it is
   held at zero: a toolbox calibration may differ from ours by such a rotation).
   Projection inverts f exactly (Newton on the incidence angle), like
   :class:`pipestitch.camera.OcamModel`, so the reported residuals are the
   model's own.

Inside this module the OCamCalib frame is used (x = rows, y = columns, z backwards,
points in front have z < 0); results are converted to the SPEC probe frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from pipestitch.calibrate.checkerboard import BoardView
from pipestitch.camera import OcamModel, fit_invpol

__all__ = ["fit_ocam"]

# OCamCalib frame (x rows, y cols, z back) <-> SPEC probe frame (x cols, y rows, z fwd).
_OCAM_TO_PROBE = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_N_INTRINSIC_FIXED = 4  # xc, yc, c, s (affine d = e = s)


def _poly_full(coef: np.ndarray) -> np.ndarray:
    """(a0, a2, ..., aN) -> ascending coefficients with a1 = 0."""
    return np.concatenate([coef[:1], [0.0], coef[1:]])


def _centred(view: BoardView, centre_rc: np.ndarray,
             affine: tuple[float, float, float] = (1.0, 0.0, 0.0)) -> np.ndarray:
    """Pixels -> pre-affine OCamCalib offsets (u along rows, v along columns)."""
    c, d, e = affine
    dr = view.pixels[:, 1] - centre_rc[0]
    dc = view.pixels[:, 0] - centre_rc[1]
    inv = 1.0 / (c - d * e)
    return np.stack([inv * (dr - d * dc), inv * (-e * dr + c * dc)], axis=1)


def _linear_extrinsics(uv: np.ndarray, xy: np.ndarray) -> list[np.ndarray]:
    """Step 1: candidate [r1 r2 t1 t2] (r3 of the first two columns from orthonormality).

    Returns up to two 3×3 arrays [[r11, r12, t1], [r21, r22, t2], [r31, r32, nan]].
    """
    u, v = uv[:, 0], uv[:, 1]
    x, y = xy[:, 0], xy[:, 1]
    m = np.stack([-v * x, -v * y, u * x, u * y, -v, u], axis=1)
    h = np.linalg.svd(m)[2][-1]
    r11, r12, r21, r22, t1, t2 = h
    a, b, c = r11 * r12 + r21 * r22, r11**2 + r21**2, r12**2 + r22**2
    r31_sq = 0.5 * ((c - b) + np.sqrt((c - b) ** 2 + 4 * a * a))
    out = []
    for sign in (1.0, -1.0):
        r31 = sign * np.sqrt(r31_sq)
        r32 = -a / r31 if abs(r31) > 1e-12 else sign * np.sqrt(max(b - c, 0.0))
        lam = 1.0 / np.sqrt(b + r31_sq)
        ext = lam * np.array([[r11, r12, t1], [r21, r22, t2], [r31, r32, np.nan]])
        p1 = ext[0, 0] * x + ext[0, 1] * y + ext[0, 2]
        p2 = ext[1, 0] * x + ext[1, 1] * y + ext[1, 2]
        if np.sum(u * p1 + v * p2) < 0:  # the ray and the point must point the same way
            ext = -ext
        out.append(ext)
    return out


def _intrinsic_rows(uv: np.ndarray, xy: np.ndarray, ext: np.ndarray,
                    degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 2 rows of one view: [powers of rho] · a + [-v or -u] · t3 = rhs."""
    u, v = uv[:, 0], uv[:, 1]
    x, y = xy[:, 0], xy[:, 1]
    rho = np.hypot(u, v)
    powers = np.stack([np.ones_like(rho)] + [rho**k for k in range(2, degree + 1)], axis=1)
    p1 = ext[0, 0] * x + ext[0, 1] * y + ext[0, 2]
    p2 = ext[1, 0] * x + ext[1, 1] * y + ext[1, 2]
    p3 = ext[2, 0] * x + ext[2, 1] * y
    lhs = np.concatenate([p2[:, None] * powers, p1[:, None] * powers])
    t3_col = np.concatenate([-v, -u])
    rhs = np.concatenate([v * p3, u * p3])
    return lhs, t3_col, rhs


def _solve_intrinsics(rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
                      ) -> tuple[np.ndarray, np.ndarray, float]:
    """Joint least squares for (a0, a2.., aN) and one t3 per view; returns RMS residual."""
    n_coef = rows[0][0].shape[1]
    n_rows = sum(r[0].shape[0] for r in rows)
    a = np.zeros((n_rows, n_coef + len(rows)))
    rhs = np.zeros(n_rows)
    i = 0
    for k, (lhs, t3_col, b) in enumerate(rows):
        n = lhs.shape[0]
        a[i:i + n, :n_coef] = lhs
        a[i:i + n, n_coef + k] = t3_col
        rhs[i:i + n] = b
        i += n
    # Normal equations: the columns are in normalised units (well scaled), and this
    # small solve runs hundreds of times in the centre search, where lstsq's SVD is
    # the bottleneck.
    try:
        sol = np.linalg.solve(a.T @ a, a.T @ rhs)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(a, rhs, rcond=None)[0]
    resid = a @ sol - rhs
    return sol[:n_coef], sol[n_coef:], float(np.sqrt(np.mean(resid**2)))


def _linear_solution(views: Sequence[BoardView], centre_rc: np.ndarray, degree: int,
                     scale_px: float, scale_mm: float
                     ) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """Steps 1 and 2 for one trial centre (normalised units); None if inconsistent."""
    exts = []
    for view in views:
        uv = _centred(view, centre_rc) / scale_px
        xy = view.object_mm[:, :2] / scale_mm
        best = None
        for ext in _linear_extrinsics(uv, xy):
            coef, t3, rms = _solve_intrinsics([_intrinsic_rows(uv, xy, ext, degree)])
            if coef[0] < 0 and (best is None or rms < best[0]):
                best = (rms, ext, t3[0])
        if best is None:
            return None
        ext = best[1].copy()
        ext[2, 2] = best[2]
        exts.append(ext)
    rows = [_intrinsic_rows(_centred(v, centre_rc) / scale_px, v.object_mm[:, :2] / scale_mm,
                            e, degree) for v, e in zip(views, exts, strict=True)]
    coef, t3, _ = _solve_intrinsics(rows)
    if coef[0] >= 0:
        return None
    for ext, t in zip(exts, t3, strict=True):
        ext[2, 2] = t
    return coef, exts


def _pose_vector(ext: np.ndarray) -> np.ndarray:
    """[r1 r2 t] (normalised units) -> (rvec, t) of the nearest rotation."""
    r1, r2 = ext[:, 0], ext[:, 1]
    rot = np.stack([r1, r2, np.cross(r1, r2)], axis=1)
    uu, _, vt = np.linalg.svd(rot)
    rot = uu @ np.diag([1.0, 1.0, np.linalg.det(uu @ vt)]) @ vt
    return np.concatenate([cv2.Rodrigues(rot)[0].ravel(), ext[:, 2]])


def _rotations(rvecs: np.ndarray) -> np.ndarray:
    """(K, 3) rotation vectors -> (K, 3, 3) matrices (Rodrigues, vectorised)."""
    angle = np.linalg.norm(rvecs, axis=1)
    axis = rvecs / np.where(angle > 0, angle, 1.0)[:, None]
    kx = np.zeros((len(rvecs), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    kx = kx - kx.transpose(0, 2, 1)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def _project_ocam(points: np.ndarray, pol: np.ndarray, centre_rc: np.ndarray,
                  affine: np.ndarray) -> np.ndarray:
    """OCamCalib-frame points -> pixels (col, row), inverting f by Newton on the angle."""
    p = np.polynomial.polynomial
    dpol = p.polyder(pol)
    n = np.hypot(points[:, 0], points[:, 1])
    theta = np.arctan2(n, -points[:, 2])
    rho = np.abs(pol[0]) * theta  # equidistant start
    for _ in range(12):
        f, df = p.polyval(rho, pol), p.polyval(rho, dpol)
        g = np.arctan2(rho, -f) - theta
        slope = (-f + rho * df) / (rho * rho + f * f)
        rho = np.maximum(rho - g / np.where(slope > 1e-12, slope, 1e-12), 0.0)
    scale = np.where(n > 0, rho / np.where(n > 0, n, 1.0), 0.0)
    u, v = points[:, 0] * scale, points[:, 1] * scale
    c, d, e = affine
    return np.stack([e * u + v + centre_rc[1], c * u + d * v + centre_rc[0]], axis=1)


class _Problem:
    """Reprojection residuals of all views for the nonlinear refinement."""

    def __init__(self, views: Sequence[BoardView], degree: int, scale_px: float,
                 scale_mm: float) -> None:
        self.views = views
        self.n_coef = degree  # a0, a2..aN
        self.scale_px, self.scale_mm = scale_px, scale_mm
        # All views' points stacked, with the index of their view: one projection call.
        self.obj = np.concatenate([np.c_[v.object_mm[:, :2] / scale_mm, np.zeros(len(v.pixels))]
                                   for v in views])
        self.index = np.concatenate([np.full(len(v.pixels), k) for k, v in enumerate(views)])
        self.pixels = np.concatenate([v.pixels for v in views])
        self.n_int = _N_INTRINSIC_FIXED + self.n_coef

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        # The antisymmetric part of the affine matrix is a rotation of the image about
        # the centre, which the views' rolls absorb exactly (a gauge freedom): d = e.
        centre, affine = x[:2], np.array([x[2], x[3], x[3]])
        coef = x[4:self.n_int]
        scale = self.scale_px ** (1 - np.arange(self.n_coef + 1))
        pol = _poly_full(coef) * scale
        poses = x[self.n_int:].reshape(-1, 6)
        return centre, affine, pol, poses

    def residuals(self, x: np.ndarray) -> np.ndarray:
        centre, affine, pol, poses = self.unpack(x)
        rots = _rotations(poses[:, :3])[self.index]
        cam = (np.einsum("nij,nj->ni", rots, self.obj) + poses[self.index, 3:]) * self.scale_mm
        return (_project_ocam(cam, pol, centre, affine) - self.pixels).ravel()

    def sparsity(self) -> lil_matrix:
        n_res = sum(2 * len(v.pixels) for v in self.views)
        s = lil_matrix((n_res, self.n_int + 6 * len(self.views)), dtype=int)
        i = 0
        for k, view in enumerate(self.views):
            n = 2 * len(view.pixels)
            s[i:i + n, :self.n_int] = 1
            s[i:i + n, self.n_int + 6 * k:self.n_int + 6 * k + 6] = 1
            i += n
        return s


def _search_centre(views: Sequence[BoardView], start_rc: np.ndarray, span_px: float,
                   degree: int, scale_px: float, scale_mm: float) -> np.ndarray:
    """Coarse-to-fine grid search of the distortion centre (OCamCalib's findcenter)."""
    problem = _Problem(views, degree, scale_px, scale_mm)
    best_rc, step = start_rc.copy(), span_px / 2
    for _ in range(5):
        best_err = np.inf
        offsets = np.arange(-2, 3) * step
        for dr in offsets:
            for dc in offsets:
                rc = best_rc + [dr, dc]
                err = _linear_error(problem, views, rc, degree, scale_px, scale_mm)
                if err < best_err:
                    best_err, cand = err, rc
        if np.isfinite(best_err):
            best_rc = cand
        step /= 2.5
    return best_rc


def _linear_error(problem: _Problem, views: Sequence[BoardView], rc: np.ndarray, degree: int,
                  scale_px: float, scale_mm: float) -> float:
    lin = _linear_solution(views, rc, degree, scale_px, scale_mm)
    if lin is None:
        return np.inf
    x = _initial_vector(rc, lin)
    r = problem.residuals(x)
    return float(np.sqrt(np.nanmean(r**2))) if np.isfinite(r).any() else np.inf


def _initial_vector(rc: np.ndarray, lin: tuple[np.ndarray, list[np.ndarray]]) -> np.ndarray:
    coef, exts = lin
    return np.concatenate([rc, [1.0, 0.0], coef, *[_pose_vector(e) for e in exts]])


def fit_ocam(views: Sequence[BoardView], width: int, height: int, *, degree: int = 4,
             centre_rc: tuple[float, float] | None = None
             ) -> tuple[OcamModel, list[tuple[np.ndarray, np.ndarray]]]:
    """Fit the Scaramuzza model to checkerboard views.

    Parameters
    ----------
    views : sequence of BoardView
        At least 3 views with their board points.
    width, height : int
        Image size in pixels.
    degree : int
        Degree of the cam2world polynomial (OCamCalib's default is 4; a1 = 0).
    centre_rc : (float, float), optional
        Start of the centre search (row, col); default the image centre.

    Returns
    -------
    camera : OcamModel
        The fitted model (``invpol`` fitted to its exact inverse).
    poses : list of (rotation (3, 3), translation (3,))
        ``R_probe_board`` and ``t`` (mm) of each view in the SPEC probe frame.

    Raises
    ------
    ValueError
        If the views do not determine a lens (e.g. all boards seen head-on at the
        centre, or fewer than 3 views).
    """
    if len(views) < 3:
        raise ValueError(f"ocam fit: expected at least 3 views, got {len(views)}")
    scale_px = 0.5 * float(min(width, height))
    scale_mm = float(np.max(np.abs(views[0].object_mm))) or 1.0
    start = (np.array([(height - 1) / 2, (width - 1) / 2]) if centre_rc is None
             else np.asarray(centre_rc, float))
    rc = _search_centre(views, start, 0.1 * min(width, height), degree, scale_px, scale_mm)
    lin = _linear_solution(views, rc, degree, scale_px, scale_mm)
    if lin is None:
        raise ValueError("ocam fit: the linear solution found no lens in front of the boards")
    problem = _Problem(views, degree, scale_px, scale_mm)
    x0 = _initial_vector(rc, lin)
    sol = least_squares(problem.residuals, x0, jac_sparsity=problem.sparsity(), x_scale="jac",
                        method="trf", max_nfev=200)
    centre, affine, pol, poses = problem.unpack(sol.x)
    camera = OcamModel(pol=tuple(float(v) for v in pol), invpol=(),
                       center_row=float(centre[0]), center_col=float(centre[1]),
                       c=float(affine[0]), d=float(affine[1]), e=float(affine[2]),
                       width=width, height=height)
    camera = OcamModel(pol=camera.pol, invpol=fit_invpol(camera), center_row=camera.center_row,
                       center_col=camera.center_col, c=camera.c, d=camera.d, e=camera.e,
                       width=width, height=height)
    rots = _rotations(poses[:, :3])
    out = [(_OCAM_TO_PROBE @ r, _OCAM_TO_PROBE @ p[3:] * scale_mm)
           for r, p in zip(rots, poses, strict=True)]
    return camera, out
