"""Ring points + a known tilt -> the pipe's oval cross-section and the probe offset.

One ring cannot tell an oval pipe from a tilted probe: the ring is a conic (five
numbers) and the unknowns are seven (tilt alpha, beta, offset dx, dy, and the
section's mean radius, ovality and its direction). An oval pipe therefore has up
to four exact pose solutions (±alpha, ±beta), not two. Given the tilt from other
evidence (the photometric refinement of :mod:`pipestitch.mosaic.refine`, which sees the
tilt linearly where the ring sees it only quadratically), the remaining five
unknowns are exactly determined by the ring. With no such evidence the tilt is
held at 0, which reads a tilt tau as an extra ovality of at most about tau²/2
(0.14 % at 3°).

The section is parametrised by its mean radius r and the ovality vector
(e cos 2phi, e sin 2phi), e = (Dmax - Dmin)/Dmean (SPEC), phi the direction of the
major axis: smooth through the circle, where phi is undefined. The wall is
q^T M q = 1 with M = [(1 + e²/4) I - [[c, s], [s, -c]]] / (r² (1 - e²/4)²) for
semi-axes r (1 ± e/2); the residual r (sqrt(q^T M q) - 1) is the radial distance
to first order. Fitted with a soft-L1 loss by a compiled Levenberg-Marquardt loop
(:mod:`pipestitch.pose._section_kernels`), ``scipy.optimize.least_squares`` where the
solution would leave the parameters' bounds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, rot_x, rot_y
from pipestitch.pose._section_kernels import fit_oval_offset
from pipestitch.pose.fit import RESELECT_SIGMAS, Hypothesis, PoseFit, plane_to_world, ring_rms_px

__all__ = ["SectionFit", "fit_section", "oval_at_zero_tilt", "oval_jacobian", "oval_residuals",
           "section_free_information", "sloping_wall_spread"]


def sloping_wall_spread(slope: float, radius_mm: float, pose: Pose,
                        plane_distance_mm: float) -> np.ndarray:
    """How far a ring on a wall whose radius changes along the pipe misleads a fit that
    takes the wall for a cylinder: (alpha, beta, dx, dy) in rad, rad, mm, mm.

    On a wall whose radius changes by ``slope`` mm per mm, a ring tilted by t from the
    axis spans R tan t along the pipe, so its points are wider on one side than on the
    other by about b = slope R tan t: its centre, the probe's offset, is misplaced by up
    to b, or its tilt by b / d (d: the laser plane's distance from the camera). A
    reducer's frames (65 to 61 mm over 20 mm, 3-4 degrees of tilt): b ~ 0.2 mm, the ring
    fit's offsets 0.15-0.33 mm off.
    """
    tilt = np.hypot(np.tan(pose.alpha), np.tan(pose.beta))
    bias = abs(slope) * radius_mm * tilt
    return np.array([bias / plane_distance_mm] * 2 + [bias] * 2)


@dataclass(frozen=True, slots=True)
class SectionFit:
    """Result of :func:`fit_section`.

    Attributes
    ----------
    pose : Pose
        The given tilt with the fitted offset.
    section : PipeSection
        Fitted cross-section (semi-axes r (1 ± e/2), major axis direction).
    ovality_std : float
        One-sigma uncertainty of the ovality (fraction).
    radius_std_mm : float
        One-sigma uncertainty of the mean radius.
    rms_mm : float
        RMS residual on the wall.
    residuals_mm : numpy.ndarray
        Residual of every point.
    information : numpy.ndarray
        4 x 4 information of (alpha, beta, dx, dy) from the ring with the section
        marginalised out: near zero along the tilt directions that ovality can mimic.
    """

    pose: Pose
    section: PipeSection
    ovality_std: float
    radius_std_mm: float
    rms_mm: float
    residuals_mm: np.ndarray
    information: np.ndarray


def _section(r: float, c: float, s: float) -> PipeSection:
    e = float(np.hypot(c, s))
    return PipeSection(r * (1 + e / 2), r * (1 - e / 2), float(np.arctan2(s, c) / 2))


def oval_residuals(x: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """Radial residuals (mm) of probe-frame points for x = (alpha, beta, dx, dy, r, c, s)."""
    rot = rot_x(x[0]) @ rot_y(x[1])
    q = points_mm @ rot[:2].T + x[2:4]
    r, c, s = x[4], x[5], x[6]
    e2 = c * c + s * s
    qx, qy = q[:, 0], q[:, 1]
    qmq = ((1 + e2 / 4) * (qx * qx + qy * qy) - (c * (qx * qx - qy * qy) + 2 * s * qx * qy)) / (
        r * r * (1 - e2 / 4) ** 2)
    return r * (np.sqrt(np.maximum(qmq, 0.0)) - 1)


def oval_jacobian(x: np.ndarray, points_mm: np.ndarray, *, tilt: bool = True) -> np.ndarray:
    """The derivatives of :func:`oval_residuals` by x = (alpha, beta, dx, dy, r, c, s):
    (N, 7); without the ``tilt`` columns (alpha, beta) (N, 5), for a fit that holds it.

    With k = 1 - e²/4 and n = (1 + e²/4)|q|² - (c (qx² - qy²) + 2 s qx qy), the
    residual is sqrt(n) / k - r (for r > 0, as the fit bounds it), so its derivatives
    are closed: by the wall point q, which alpha, beta (through the rotation's
    derivatives) and the offset move, and by r, c and s. Zero by q, c and s where n
    is not positive (the residual's clamp).
    """
    a, b, c, s = x[0], x[1], x[5], x[6]
    tilt_x, tilt_y = rot_x(a), rot_y(b)
    q = points_mm @ (tilt_x @ tilt_y)[:2].T + x[2:4]
    e2 = c * c + s * s
    k = 1 - e2 / 4
    qx, qy = q[:, 0], q[:, 1]
    sq, diff, cross = qx * qx + qy * qy, qx * qx - qy * qy, qx * qy
    n = (1 + e2 / 4) * sq - (c * diff + 2 * s * cross)
    root = np.sqrt(np.maximum(n, 0.0))
    half = 1.0 / (2 * k * np.where(root > 0, root, np.inf))   # d(sqrt(n) / k) / dn
    g_x = half * (2 * (1 + e2 / 4) * qx - 2 * (c * qx + s * qy))
    g_y = half * (2 * (1 + e2 / 4) * qy + 2 * (c * qy - s * qx))
    d_c = half * (c / 2 * sq - diff) + np.where(root > 0, root, 0.0) * c / (2 * k * k)
    d_s = half * (s / 2 * sq - 2 * cross) + np.where(root > 0, root, 0.0) * s / (2 * k * k)
    rest = [g_x, g_y, np.full_like(qx, -1.0), d_c, d_s]
    if not tilt:
        return np.column_stack(rest)
    d_tilt_x, d_tilt_y = rot_x(a + np.pi / 2), rot_y(b + np.pi / 2)
    d_tilt_x[0, 0], d_tilt_y[1, 1] = 0.0, 0.0   # the derivative of the fixed axis' 1
    q_a = points_mm @ (d_tilt_x @ tilt_y)[:2].T
    q_b = points_mm @ (tilt_x @ d_tilt_y)[:2].T
    return np.column_stack([g_x * q_a[:, 0] + g_y * q_a[:, 1], g_x * q_b[:, 0] + g_y * q_b[:, 1],
                            *rest])


def fit_section(points_mm: np.ndarray, pose: Pose, radius_mm: float, *,
                start: PipeSection | None = None, noise_mm: float = 0.05) -> SectionFit:
    """Fit the offset and an oval section to ring points with the tilt held fixed.

    Parameters
    ----------
    points_mm : numpy.ndarray, shape (N, 3)
        Ring points on the laser plane, probe frame (:attr:`RingPoints.points_mm`).
    pose : Pose
        alpha, beta are held; dx, dy start the fit.
    radius_mm : float
        Starting mean radius.
    start : PipeSection, optional
        Starting section (e.g. the previous round's); a circle otherwise.
    noise_mm : float
        Point noise on the wall: the soft-L1 scale.

    Returns
    -------
    SectionFit
    """
    if start is not None and not start.is_circle:
        e = start.ovality
        c0, s0 = e * np.cos(2 * start.angle), e * np.sin(2 * start.angle)
        if start.b_mm > start.a_mm:   # major axis along angle + 90°
            c0, s0 = -c0, -s0
        x0 = np.array([pose.dx_mm, pose.dy_mm, start.mean_radius_mm, c0, s0])
    else:
        x0 = np.array([pose.dx_mm, pose.dy_mm, radius_mm, 0.0, 0.0])
    tilt = np.array([pose.alpha, pose.beta])

    x0[3:] = np.clip(x0[3:], -0.49, 0.49)
    x = np.concatenate([tilt, _fit_offset_and_section(points_mm, tilt, x0, noise_mm)])
    resid, info = _information(x, points_mm)
    cov = np.linalg.pinv(info[2:, 2:])
    e = float(np.hypot(x[5], x[6]))
    grad = np.array([x[5], x[6]]) / e if e > 0 else np.array([1.0, 0.0])
    ovality_std = float(np.sqrt(max(grad @ cov[3:, 3:] @ grad, 0.0)))
    pose_info = _section_marginalised(info)
    return SectionFit(Pose(pose.alpha, pose.beta, float(x[2]), float(x[3])),
                      _section(*x[4:]), ovality_std, float(np.sqrt(max(cov[2, 2], 0.0))),
                      float(np.sqrt(np.mean(resid**2))), resid, pose_info)


# Ovality components within ±0.5 (50 %, far past any pipe): the model needs e < 2.
SECTION_BOUNDS = np.array([[-np.inf, -np.inf, 1e-3, -0.5, -0.5],
                           [np.inf, np.inf, np.inf, 0.5, 0.5]])
SECTION_X_SCALE = np.array([1.0, 1.0, 1.0, 0.01, 0.01])   # dx, dy, r (mm); c, s


def _fit_offset_and_section(points_mm: np.ndarray, tilt: np.ndarray, x0: np.ndarray,
                            noise_mm: float) -> np.ndarray:
    """(dx, dy, r, c, s) of :func:`fit_section`: the compiled robust solve
    (:func:`pipestitch.pose._section_kernels.fit_oval_offset`), or where that leaves
    the bounds or does not converge, ``scipy.optimize.least_squares`` with them (the
    same soft-L1 cost)."""
    rotated = np.ascontiguousarray(points_mm @ (rot_x(tilt[0]) @ rot_y(tilt[1]))[:2].T)
    x, converged = fit_oval_offset(rotated, np.asarray(x0, np.float64), float(noise_mm),
                                   SECTION_X_SCALE, SECTION_BOUNDS)
    if converged:
        return x

    # imported here: scipy.optimize (and the scipy.spatial it loads) takes ~0.15 s to
    # import, and this fallback is rare, so a run that never takes it does not pay that
    from scipy.optimize import least_squares

    def fun(v: np.ndarray) -> np.ndarray:
        return oval_residuals(np.concatenate([tilt, v]), points_mm)

    def jac(v: np.ndarray) -> np.ndarray:
        return oval_jacobian(np.concatenate([tilt, v]), points_mm, tilt=False)

    return least_squares(fun, x0, jac=jac, loss="soft_l1", f_scale=noise_mm, method="trf",
                         x_scale=SECTION_X_SCALE, bounds=tuple(SECTION_BOUNDS)).x


def _information(x: np.ndarray, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The residuals at ``x`` (alpha, beta, dx, dy, r, c, s) and the 7 x 7 information
    of the parameters (Gauss-Newton, scaled by the residuals' variance)."""
    resid = oval_residuals(x, points_mm)
    jac = oval_jacobian(x, points_mm)
    dof = max(1, len(resid) - 5)
    return resid, jac.T @ jac / max(float(resid @ resid) / dof, 1e-12)


def _section_marginalised(info: np.ndarray) -> np.ndarray:
    """The 4 x 4 information of (alpha, beta, dx, dy) with (r, c, s) marginalised out
    (Schur complement), made positive semi-definite up to rounding."""
    pose_info = info[:4, :4] - info[:4, 4:] @ np.linalg.pinv(info[4:, 4:]) @ info[4:, :4]
    evals, evecs = np.linalg.eigh((pose_info + pose_info.T) / 2)
    return (evecs * np.maximum(evals, 0.0)) @ evecs.T


def section_free_information(points_mm: np.ndarray, pose: Pose,
                             radius_mm: float) -> np.ndarray:
    """What a frame's ring says about its pose when the pipe's section is not assumed
    round: the 4 x 4 information of (alpha, beta, dx, dy) at a circle fit (``pose``,
    ``radius_mm``) with the section's radius and ovality marginalised out. Near zero
    along the tilt directions an ovality can mimic, so a refinement that takes it as
    its prior measures those from the LED frames rather than keeping the ring's
    circle tilt (a 0.6 % oval read as a round pipe: several degrees of tilt)."""
    x = np.array([pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm, radius_mm, 0.0, 0.0])
    return _section_marginalised(_information(x, points_mm)[1])


def oval_at_zero_tilt(fit: PoseFit, camera: CameraModel) -> PoseFit:
    """The frame refitted as an oval pipe with the tilt held at 0.

    For a frame whose circle pose the probe body cannot hold: an oval pipe read as a
    circle looks like a strong tilt (5 % ovality ~ 18°). The result has model
    ``"oval/tilt-0"``: offset and section from the ring with the tilt unobserved and
    held at 0 (the photometric refinement of ``pipestitch run`` then measures it, and
    keeps the oval only where it is significant); both hypotheses coincide. A fit
    without ring points is returned unchanged.
    """
    if not fit.ok or fit.ring is None:
        return fit
    h = fit.hypotheses[0]
    plane = fit.ring.plane
    centre = plane_to_world(h.pose, plane)[1]   # world (x, y) of the plane centre
    # untilted, the plane centre d·n lands at d·n[:2] + offset: start the offset there
    offset = centre - plane.distance_mm * plane.normal[:2]
    noise_mm = fit.ring.noise_mm
    sf = fit_section(fit.ring.points_mm, Pose(0.0, 0.0, *offset), h.radius_mm, noise_mm=noise_mm)
    keep = np.abs(sf.residuals_mm) < RESELECT_SIGMAS * noise_mm
    rms_px = ring_rms_px(sf.pose, sf.section.mean_radius_mm,
                         fit.ring.pixels[keep].astype(np.float64),
                         fit.ring.uv[keep].astype(np.float64), sf.residuals_mm[keep], camera,
                         plane)
    oval = Hypothesis(sf.pose, sf.section.mean_radius_mm, float("nan"), sf.rms_mm, rms_px,
                      {"dx_mm": float("nan"), "dy_mm": float("nan"),
                       "radius_mm": sf.radius_std_mm, "ovality": sf.ovality_std},
                      sf.information, sf.section, std_scale=h.std_scale)   # same ring points
    return replace(fit, hypotheses=(oval, oval), model="oval/tilt-0")
