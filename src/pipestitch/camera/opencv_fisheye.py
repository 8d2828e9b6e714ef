"""OpenCV fisheye (Kannala-Brandt, K and D = k1..k4) model, valid past 90°.

OpenCV's model is theta_d = theta (1 + k1 theta² + k2 theta⁴ + k3 theta⁶ + k4 theta⁸)
with theta the incidence angle, then ``u = fx (x_d + alpha y_d) + cx``,
``v = fy y_d + cy`` where (x_d, y_d) = theta_d (X, Y) / sqrt(X² + Y²).

``cv2.fisheye.projectPoints`` computes theta as ``atan(r / z)`` after dividing by z,
so a point behind the image plane (z < 0, theta > 90°) is folded back into the front
hemisphere and lands on the wrong pixel. Here theta = atan2(sqrt(X² + Y²), Z), the
same polynomial is evaluated on the true angle, and unprojection inverts it exactly
(lookup table + Newton), so the model is valid over a whole ~185° field of view.
For theta < 90° the result equals OpenCV's to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipestitch.camera.base import as_points, invert_monotonic, rays_from_angles

__all__ = ["OpenCVFisheyeModel"]


@dataclass(frozen=True)
class OpenCVFisheyeModel:
    """OpenCV fisheye camera.

    Parameters
    ----------
    fx, fy, cx, cy : float
        Focal lengths and principal point in pixels (cx = column, cy = row).
    k : tuple of 4 float
        Distortion coefficients k1..k4 (OpenCV ``D``).
    width, height : int
        Image size in pixels.
    skew : float
        OpenCV's ``alpha`` (K[0, 1] / fx); 0 for nearly all cameras.
    max_theta_deg : float
        Upper bound on the valid incidence angle; the model also stops where
        theta_d(theta) stops increasing.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    k: tuple[float, float, float, float]
    width: int
    height: int
    skew: float = 0.0
    max_theta_deg: float = 120.0
    _theta_table: np.ndarray = field(init=False, repr=False, compare=False)
    _thetad_table: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        k = tuple(float(v) for v in self.k)
        values = (self.fx, self.fy, self.cx, self.cy, self.skew, *k)
        if len(k) != 4 or not np.all(np.isfinite(values)):
            raise ValueError(f"opencv_fisheye: K and D must be finite with 4 coefficients, got {k}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"opencv_fisheye: focal lengths must be positive, got {self.fx}, "
                             f"{self.fy}")
        object.__setattr__(self, "k", k)
        theta = np.linspace(0.0, np.deg2rad(min(self.max_theta_deg, 179.0)), 8193)
        thetad, slope = self._distort(theta)
        stop = int(np.argmax(slope <= 0)) if np.any(slope <= 0) else theta.size
        if stop < 16:
            raise ValueError("opencv_fisheye: D does not describe a lens (theta_d not increasing)")
        object.__setattr__(self, "_theta_table", theta[:stop])
        object.__setattr__(self, "_thetad_table", thetad[:stop])

    def _distort(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta_d(theta) and its derivative."""
        k1, k2, k3, k4 = self.k
        t2 = theta * theta
        poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        return theta * poly, dpoly

    @property
    def max_incidence_rad(self) -> float:
        """Largest incidence angle the model is valid for (radians)."""
        return float(self._theta_table[-1])

    def project(self, points: np.ndarray) -> np.ndarray:
        """Probe-frame points (N, 3) -> pixels (N, 2) as (col, row); NaN if invalid."""
        pts = as_points(points, 3, "points")
        r = np.hypot(pts[:, 0], pts[:, 1])
        theta = np.arctan2(r, pts[:, 2])
        thetad, _ = self._distort(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(r > 0, thetad / r, 0.0)
        xd, yd = pts[:, 0] * scale, pts[:, 1] * scale
        out = np.stack([self.fx * (xd + self.skew * yd) + self.cx, self.fy * yd + self.cy], axis=1)
        out[~((theta <= self.max_incidence_rad) & (np.linalg.norm(pts, axis=1) > 0))] = np.nan
        return out

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) as (col, row) -> unit rays (N, 3); NaN outside the valid range."""
        px = as_points(pixels, 2, "pixels")
        yd = (px[:, 1] - self.cy) / self.fy
        xd = (px[:, 0] - self.cx) / self.fx - self.skew * yd
        thetad = np.hypot(xd, yd)
        valid = thetad <= self._thetad_table[-1]
        theta = invert_monotonic(self._distort, np.where(valid, thetad, 0.0),
                                 self._theta_table, self._thetad_table)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_phi = np.where(thetad > 0, xd / thetad, 1.0)
            sin_phi = np.where(thetad > 0, yd / thetad, 0.0)
        rays = rays_from_angles(theta, cos_phi, sin_phi)
        rays[~valid] = np.nan
        return rays

    def scaled(self, factor: float) -> OpenCVFisheyeModel:
        """The same lens on a sensor resampled by ``factor`` (pixel centres kept)."""
        s = float(factor)
        return OpenCVFisheyeModel(
            fx=self.fx * s, fy=self.fy * s, cx=(self.cx + 0.5) * s - 0.5,
            cy=(self.cy + 0.5) * s - 0.5, k=self.k, width=round(self.width * s),
            height=round(self.height * s), skew=self.skew, max_theta_deg=self.max_theta_deg,
        )

    @property
    def camera_matrix(self) -> np.ndarray:
        """OpenCV's K (3 × 3)."""
        return np.array([[self.fx, self.skew * self.fx, self.cx], [0, self.fy, self.cy], [0, 0, 1]])
