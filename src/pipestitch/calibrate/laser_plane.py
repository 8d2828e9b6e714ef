"""Laser-plane calibration: the plane's normal and distance in the probe frame.

Data: laser frames taken in a straight pipe of known radius r at several probe
poses. Model: one plane {p : n·p = d} shared by all frames (n a unit vector near
+z, parametrised by its slopes (n_x/n_z, n_y/n_z)) and one pose (alpha, beta, dx,
dy) per frame (SPEC pose; roll and z do not change the ring). A ring pixel's ray
meets the plane at p = ray·d/(n·ray); its distance from the pipe axis after the
frame's pose must be r. All unknowns are solved at once by
``scipy.optimize.least_squares`` (soft-L1 loss, sparse Jacobian), then points
beyond 5 robust sigma are dropped and the fit repeated.

What is observable (see docs/calibration.md for the argument):

* From **one** frame, nothing about n: the ring's rays form a cone, every plane
  through that cone cuts a conic, and a plane of any tilt at the right distance
  cuts an ellipse whose minor semi-axis is r — a cylinder of radius r (and its
  mirror) then passes through it. A plane tilt trades exactly against the pose tilt,
  and d follows from n.
* With **several** frames at different tilts and offsets, the distance each frame
  would need for a given wrong tilt differs between frames, so n becomes
  observable — weakly: the frames constrain it through how the ring's shape
  changes with the pose, not directly. The fit reports the 1-sigma uncertainty of
  n (from the Jacobian); frames with a varied tilt (several degrees, in different
  directions) and offsets make it small. d is well determined (given r).
* Roll about the pipe axis and the axial position are not observable and not
  needed. The mirror hypothesis of each frame fits equally for any plane, so the
  start's choice between mirrors does not change (n, d).

What this module does not do: detect the ring (:mod:`pipestitch.pose.ring`) or pick
the frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from pipestitch.geometry import Pose

__all__ = ["LaserPlaneFit", "calibrate_laser_plane", "normal_tilt_deg",
           "plane_intersections"]


@dataclass(frozen=True)
class LaserPlaneFit:
    """Result of :func:`calibrate_laser_plane`.

    Attributes
    ----------
    normal : numpy.ndarray, shape (3,)
        Unit normal of the laser plane in the probe frame (n_z > 0).
    distance_mm : float
        d: the plane is {p : normal·p = d}.
    normal_std_deg : (float, float)
        1-sigma uncertainty of the plane's tilt about probe y and x
        (slopes n_x/n_z and n_y/n_z as angles).
    distance_std_mm : float
        1-sigma uncertainty of d.
    poses : list of Pose
        The pose fitted to each frame with this plane.
    rms_mm : float
        RMS distance of the used ring points from the wall.
    n_points : int
        Ring points used (after outlier rejection).
    """

    normal: np.ndarray
    distance_mm: float
    normal_std_deg: tuple[float, float]
    distance_std_mm: float
    poses: list[Pose]
    rms_mm: float
    n_points: int

    @property
    def tilt_deg(self) -> float:
        """Angle between the plane's normal and the optical axis (degrees)."""
        return normal_tilt_deg(self.normal)


def normal_tilt_deg(normal: np.ndarray) -> float:
    """Angle between ``normal`` and +z, degrees."""
    n = np.asarray(normal, float)
    return float(np.degrees(np.arccos(np.clip(n[2] / np.linalg.norm(n), -1.0, 1.0))))


def _normal(slopes: np.ndarray) -> np.ndarray:
    n = np.array([slopes[0], slopes[1], 1.0])
    return n / np.linalg.norm(n)


def plane_intersections(rays: np.ndarray, normal: np.ndarray, distance_mm: float) -> np.ndarray:
    """Points where probe-frame rays meet the plane {p : normal·p = d}; NaN when they miss."""
    with np.errstate(invalid="ignore", divide="ignore"):
        s = distance_mm / (rays @ np.asarray(normal, float))
    s = np.where(s > 0, s, np.nan)
    return rays * s[:, None]


def _frame_residuals(pose4: np.ndarray, rays: np.ndarray, normal: np.ndarray, d: float,
                     radius: float) -> np.ndarray:
    pts = plane_intersections(rays, normal, d)
    pose = Pose(*pose4)
    w = pts @ pose.rotation_world_probe().T
    return np.hypot(w[:, 0] + pose4[2], w[:, 1] + pose4[3]) - radius


class _Problem:
    def __init__(self, rays: Sequence[np.ndarray], radius: float) -> None:
        self.rays = list(rays)
        self.radius = radius

    def residuals(self, x: np.ndarray) -> np.ndarray:
        normal, d = _normal(x[:2]), x[2]
        poses = x[3:].reshape(-1, 4)
        return np.concatenate([_frame_residuals(p, r, normal, d, self.radius)
                               for p, r in zip(poses, self.rays, strict=True)])

    def sparsity(self) -> lil_matrix:
        n = sum(len(r) for r in self.rays)
        s = lil_matrix((n, 3 + 4 * len(self.rays)), dtype=int)
        i = 0
        for k, r in enumerate(self.rays):
            s[i:i + len(r), :3] = 1
            s[i:i + len(r), 3 + 4 * k:7 + 4 * k] = 1
            i += len(r)
        return s


def _solve(problem: _Problem, x0: np.ndarray, noise_mm: float) -> np.ndarray:
    return least_squares(problem.residuals, x0, jac_sparsity=problem.sparsity(), loss="soft_l1",
                         f_scale=noise_mm, x_scale="jac", method="trf", max_nfev=200).x


def calibrate_laser_plane(rays: Sequence[np.ndarray], start_poses: Sequence[Pose],
                          radius_mm: float, *, start_distance_mm: float = 16.0,
                          noise_mm: float = 0.05) -> LaserPlaneFit:
    """Estimate the laser plane (normal and distance) from rings in a pipe of known radius.

    Parameters
    ----------
    rays : sequence of numpy.ndarray, shape (N_k, 3)
        Probe-frame rays of each frame's ring pixels (camera ``unproject``).
    start_poses : sequence of Pose
        A starting pose per frame (e.g. from :func:`pipestitch.pose.fit.fit_pose`
        with the nominal plane; either mirror hypothesis).
    radius_mm : float
        Inner radius of the (straight, circular) calibration pipe.
    start_distance_mm : float
        Starting plane distance (the nominal d).
    noise_mm : float
        Expected point noise on the wall: the robust loss scale.

    Returns
    -------
    LaserPlaneFit

    Raises
    ------
    ValueError
        Fewer than 3 frames, or a frame with fewer than 12 usable rays.
    """
    if len(rays) < 3 or len(rays) != len(start_poses):
        raise ValueError(f"laser plane: expected at least 3 frames with a start pose each, got "
                         f"{len(rays)} frames and {len(start_poses)} poses")
    kept = [np.asarray(r, float)[np.all(np.isfinite(r), axis=1) & (np.asarray(r)[:, 2] > 1e-3)]
            for r in rays]
    small = [k for k, r in enumerate(kept) if len(r) < 12]
    if small:
        raise ValueError(f"laser plane: frame(s) {small} have fewer than 12 usable ring points")
    x = np.concatenate([[0.0, 0.0, start_distance_mm],
                        *[[p.alpha, p.beta, p.dx_mm, p.dy_mm] for p in start_poses]])
    for _ in range(2):
        problem = _Problem(kept, radius_mm)
        x = _solve(problem, x, noise_mm)
        res = np.split(problem.residuals(x), np.cumsum([len(r) for r in kept])[:-1])
        sigma = 1.4826 * float(np.median(np.abs(np.concatenate(res))))
        limit = max(5 * sigma, 3 * noise_mm)
        kept = [r[np.abs(e) <= limit] for r, e in zip(kept, res, strict=True)]
    problem = _Problem(kept, radius_mm)
    x = _solve(problem, x, noise_mm)
    return _result(problem, x)


def _result(problem: _Problem, x: np.ndarray) -> LaserPlaneFit:
    res = problem.residuals(x)
    jac = _numeric_jacobian(problem, x)
    dof = max(res.size - x.size, 1)
    sigma2 = float(res @ res) / dof
    cov = np.linalg.pinv(jac.T @ jac) * sigma2
    std = np.sqrt(np.clip(np.diag(cov)[:3], 0, None))
    poses = [Pose(*p) for p in x[3:].reshape(-1, 4)]
    return LaserPlaneFit(_normal(x[:2]), float(x[2]),
                         (float(np.degrees(std[0])), float(np.degrees(std[1]))), float(std[2]),
                         poses, float(np.sqrt(np.mean(res**2))), int(res.size))


def _numeric_jacobian(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """Central differences (dense: only used once, for the uncertainty)."""
    steps = 1e-6 * np.maximum(np.abs(x), 1.0)
    cols = []
    for i, h in enumerate(steps):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((problem.residuals(x + e) - problem.residuals(x - e)) / (2 * h))
    return np.stack(cols, axis=1)
