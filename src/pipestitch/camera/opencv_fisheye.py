"""OpenCV fisheye (Kannala-Brandt, K and D = k1..k4) model, valid past 90°.

OpenCV's model is theta_d = theta (1 + k1 theta² + k2 theta⁴ + k3 theta⁶ + k4 theta⁸)
with theta the incidence angle, then ``u = fx (x_d + alpha y_d) + cx``,
``v = fy y_d + cy`` where (x_d, y_d) = theta_d (X, Y) / sqrt(X² + Y²).

``cv2.fisheye.projectPoints`` computes theta as ``atan(r / z)`` after dividing by z,
so a point behind the image plane (z < 0, theta > 90°) is folded back into the front
hemisphere and lands on the wrong pixel. Here theta = atan2(sqrt(X² + Y²), Z), the
same polynomial is evaluated on the true angle, and unprojection inverts it exactly
(lookup table + Newton, compiled with numba), so the model is valid over a whole ~185°
field of view. For theta < 90° the result equals OpenCV's to rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)
from pipestitch.camera.base import OPENCV_FISHEYE, RayKernel, as_points

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
    _k_array: np.ndarray = field(init=False, repr=False, compare=False)
    _intrinsics: np.ndarray = field(init=False, repr=False, compare=False)
    _thetad_start: np.ndarray = field(init=False, repr=False, compare=False)
    _ray_kernel: RayKernel = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        k = tuple(float(v) for v in self.k)
        values = (self.fx, self.fy, self.cx, self.cy, self.skew, *k)
        if len(k) != 4 or not np.all(np.isfinite(values)):
            raise ValueError(f"opencv_fisheye: K and D must be finite with 4 coefficients, got {k}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"opencv_fisheye: focal lengths must be positive, got {self.fx}, "
                             f"{self.fy}")
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "_k_array", np.array(k))
        object.__setattr__(self, "_intrinsics", np.array(
            [self.fx, self.fy, self.cx, self.cy, self.skew], dtype=np.float64))
        theta = np.linspace(0.0, np.deg2rad(min(self.max_theta_deg, 179.0)), 8193)
        thetad, slope = self._distort(theta)
        stop = int(np.argmax(slope <= 0)) if np.any(slope <= 0) else theta.size
        if stop < 16:
            raise ValueError("opencv_fisheye: D does not describe a lens (theta_d not increasing)")
        object.__setattr__(self, "_theta_table", theta[:stop])
        object.__setattr__(self, "_thetad_table", thetad[:stop])
        # the table entry at or below each of stop equal steps of theta_d (as OcamModel)
        steps = np.arange(stop + 1) * (thetad[stop - 1] / stop)
        start = np.searchsorted(thetad[:stop], steps, side="right") - 1
        object.__setattr__(self, "_thetad_start", np.clip(start, 0, stop - 2).astype(np.int64))
        object.__setattr__(self, "_ray_kernel", RayKernel(
            OPENCV_FISHEYE, self._intrinsics, self._k_array, self._theta_table,
            self._thetad_table, self._thetad_start))

    def _distort(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta_d(theta) and its derivative."""
        return _distort_all(np.ascontiguousarray(theta, dtype=np.float64), self._k_array)

    @property
    def max_incidence_rad(self) -> float:
        """Largest incidence angle the model is valid for (radians)."""
        return float(self._theta_table[-1])

    @property
    def ray_kernel(self) -> RayKernel:
        """:meth:`unproject`'s compiled loop as data (for ``camera.kernels.rays_of``)."""
        return self._ray_kernel

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
        px = np.ascontiguousarray(as_points(pixels, 2, "pixels"))
        return ray_loop(px, self._intrinsics, self._k_array, self._theta_table,
                        self._thetad_table, self._thetad_start)

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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _distort_at(theta: float, k: np.ndarray) -> tuple[float, float]:
    """theta_d(theta) = theta (1 + k1 theta² + ... + k4 theta⁸) and its derivative."""
    t2 = theta * theta
    poly = 1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
    dpoly = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
    return theta * poly, dpoly


@numba.njit(cache=True, nogil=True)
def _distort_all(theta: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_distort_at` of every angle in a 1-D array."""
    thetad, slope = np.empty(theta.shape[0]), np.empty(theta.shape[0])
    for i in range(theta.shape[0]):
        thetad[i], slope[i] = _distort_at(theta[i], k)
    return thetad, slope


@numba.njit(cache=True, nogil=True, error_model="numpy")
def ray_loop(pixels: np.ndarray, intrinsics: np.ndarray, k: np.ndarray,
             theta_table: np.ndarray, thetad_table: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Unit rays of pixels (col, row); NaN beyond the table's largest theta_d or NaN.

    ``intrinsics`` is (fx, fy, cx, cy, skew). theta_d(theta) is inverted exactly: the
    table (increasing samples over the valid range; ``start`` indexes it by equal steps
    of theta_d, so the search from there is a step or two) gives the start and Newton
    polishes it (clipped to the table's range) until a step is below 1e-13 of that
    range: at most 6 steps, 2 from the table. A fitted inverse polynomial would be good
    to ~0.01 px only, and OpenCV's ``fisheye.undistortPoints`` folds rays past 90° back
    (module docstring); compiled because as array expressions the look-up and the Newton
    steps cost more per call than the pose fit they feed.
    """
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    skew = intrinsics[4]
    lo, hi, last = theta_table[0], theta_table[-1], theta_table.shape[0] - 2
    tol = 1e-13 * max(abs(lo), abs(hi), 1.0)
    inv_step = (start.shape[0] - 1) / thetad_table[-1]
    out = np.empty((pixels.shape[0], 3))
    for i in range(pixels.shape[0]):
        yd = (pixels[i, 1] - cy) / fy
        xd = (pixels[i, 0] - cx) / fx - skew * yd
        thetad = math.sqrt(xd * xd + yd * yd)
        if not thetad <= thetad_table[-1]:
            out[i, 0] = out[i, 1] = out[i, 2] = np.nan
            continue
        j = start[min(int(thetad * inv_step), start.shape[0] - 1)]
        while j < last and thetad_table[j + 1] <= thetad:
            j += 1
        theta = theta_table[j] + ((theta_table[j + 1] - theta_table[j]) * (thetad - thetad_table[j])
                                  / (thetad_table[j + 1] - thetad_table[j]))
        for _ in range(6):
            value, slope = _distort_at(theta, k)
            step = (value - thetad) / slope
            theta = min(max(theta - step, lo), hi)
            if abs(step) <= tol:
                break
        s = math.sin(theta)
        cos_phi, sin_phi = (xd / thetad, yd / thetad) if thetad > 0 else (1.0, 0.0)
        out[i, 0], out[i, 1], out[i, 2] = s * cos_phi, s * sin_phi, math.cos(theta)
    return out
