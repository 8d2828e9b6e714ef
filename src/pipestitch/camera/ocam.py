"""Scaramuzza / OCamCalib omnidirectional camera model (pure maths, no file reading).

Conventions follow OCamCalib's ``calib_results.txt`` exactly (see SPEC and
``docs/conventions.md``): ``pol`` is the cam2world polynomial F(rho) in ascending
powers of rho (pixels), ``invpol`` the fitted world2cam polynomial rho(t) with
t = atan(z / sqrt(x² + y²)), ``center`` is (row, column) 0-based and the affine
part maps ``[row - xc, col - yc] = [[c, d], [e, 1]] [u, v]``. OCamCalib's own frame
has x along rows, y along columns and z backwards; the SPEC probe frame is
(x_probe, y_probe, z_probe) = (y_ocam, x_ocam, -z_ocam).

``project`` does not use ``invpol``: it inverts ``pol`` exactly (lookup table +
Newton, see :func:`pipestitch.camera.base.invert_monotonic`), so that project and
unproject agree to float64 rounding (~1e-12 px) over the whole image circle,
including rays more than 90° off the axis. ``invpol`` is kept for export and for
comparison with other tools (:meth:`OcamModel.project_invpol`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipestitch.camera.base import as_points, invert_monotonic

__all__ = ["OcamModel", "fit_invpol"]


@dataclass(frozen=True)
class OcamModel:
    """Scaramuzza omnidirectional model.

    Parameters
    ----------
    pol : tuple of float
        cam2world polynomial F(rho), ascending powers, rho in pixels, F(0) < 0.
    invpol : tuple of float
        world2cam polynomial rho(t), ascending powers (may be empty).
    center_row, center_col : float
        Distortion centre (OCamCalib ``xc``, ``yc``), 0-based pixels.
    c, d, e : float
        Affine (stretch) parameters.
    width, height : int
        Image size in pixels.
    """

    pol: tuple[float, ...]
    invpol: tuple[float, ...]
    center_row: float
    center_col: float
    c: float
    d: float
    e: float
    width: int
    height: int
    _rho_table: np.ndarray = field(init=False, repr=False, compare=False)
    _theta_table: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pol = tuple(float(v) for v in self.pol)
        values = (*pol, self.center_row, self.center_col, self.c, self.d, self.e)
        if len(pol) < 2 or not np.all(np.isfinite(values)):
            raise ValueError(f"ocam: pol and parameters must be finite, got pol={self.pol}")
        if pol[0] >= 0:
            raise ValueError(f"ocam: pol[0] must be negative (OCamCalib convention), got {pol[0]}")
        if abs(self.c - self.d * self.e) < 1e-9:
            raise ValueError("ocam: affine matrix [[c, d], [e, 1]] is singular")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"ocam: image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "pol", pol)
        object.__setattr__(self, "invpol", tuple(float(v) for v in self.invpol))
        rho, theta = self._monotonic_table()
        object.__setattr__(self, "_rho_table", rho)
        object.__setattr__(self, "_theta_table", theta)

    # --- radial function ---------------------------------------------------------
    def _theta_of_rho(self, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Incidence angle theta(rho) = atan2(rho, -F(rho)) and its derivative."""
        p = np.polynomial.polynomial
        f = p.polyval(rho, self.pol)
        df = p.polyval(rho, p.polyder(self.pol))
        theta = np.arctan2(rho, -f)
        slope = (-f + rho * df) / (rho * rho + f * f)
        return theta, slope

    def _monotonic_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Sample theta(rho) from the centre out to where it stops increasing.

        The valid domain ends at the first of: the farthest image corner (plus a
        margin), theta reaching pi, or theta(rho) turning back (a polynomial fitted
        inside the image circle may do so just outside it).
        """
        corners = np.array([[0, 0], [0, self.width - 1], [self.height - 1, 0],
                            [self.height - 1, self.width - 1]], dtype=float)
        u, v = self._unaffine(corners[:, 0], corners[:, 1])
        rho_lim = 1.05 * float(np.max(np.hypot(u, v))) + 2.0
        rho = np.linspace(0.0, rho_lim, 8193)
        theta, slope = self._theta_of_rho(rho)
        bad = (slope <= 0) | (theta >= np.pi - 1e-6)
        stop = int(np.argmax(bad)) if bad.any() else rho.size
        if stop < 16:
            raise ValueError("ocam: pol does not describe a lens (theta(rho) not increasing)")
        return rho[:stop], theta[:stop]

    def _unaffine(self, row: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dr, dc = row - self.center_row, col - self.center_col
        invdet = 1.0 / (self.c - self.d * self.e)
        u = invdet * (dr - self.d * dc)
        v = invdet * (-self.e * dr + self.c * dc)
        return u, v

    @property
    def max_incidence_rad(self) -> float:
        """Largest incidence angle the polynomial is valid for (radians)."""
        return float(self._theta_table[-1])

    @property
    def max_rho_px(self) -> float:
        """Radius (pre-affine pixels) of the valid image circle."""
        return float(self._rho_table[-1])

    # --- projection ----------------------------------------------------------------
    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) as (col, row) -> unit rays (N, 3) in the SPEC probe frame.

        Pixels outside the valid image circle give NaN rays.
        """
        px = as_points(pixels, 2, "pixels")
        u, v = self._unaffine(px[:, 1], px[:, 0])
        rho = np.hypot(u, v)
        f = np.polynomial.polynomial.polyval(rho, self.pol)
        rays = np.stack([v, u, -f], axis=1)  # (y_ocam, x_ocam, -z_ocam)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        rays[~(rho <= self.max_rho_px)] = np.nan
        return rays

    def project(self, points: np.ndarray) -> np.ndarray:
        """Probe-frame points (N, 3) -> pixels (N, 2) as (col, row).

        Exact inverse of :meth:`unproject` (Newton on theta(rho)); NaN for points
        beyond the valid incidence angle, at the origin or non-finite.
        """
        pts = as_points(points, 3, "points")
        n = np.hypot(pts[:, 0], pts[:, 1])
        theta = np.arctan2(n, pts[:, 2])
        valid = (theta <= self.max_incidence_rad) & (np.linalg.norm(pts, axis=1) > 0)
        theta_ok = np.where(valid, theta, 0.0)
        rho = invert_monotonic(self._theta_of_rho, theta_ok, self._rho_table, self._theta_table)
        return self._rho_to_pixels(pts, n, rho, valid)

    def project_invpol(self, points: np.ndarray) -> np.ndarray:
        """Project with the fitted ``invpol`` as OCamCalib's C ``world2cam`` does.

        Accurate only to the fit (~0.01 px); for comparison with other tools.
        """
        if not self.invpol:
            raise ValueError("ocam: this model has no invpol")
        pts = as_points(points, 3, "points")
        n = np.hypot(pts[:, 0], pts[:, 1])
        t = np.arctan2(-pts[:, 2], n)  # OCamCalib: atan(z_ocam / n), z_ocam = -z_probe
        rho = np.polynomial.polynomial.polyval(t, self.invpol)
        valid = np.arctan2(n, pts[:, 2]) <= self.max_incidence_rad
        return self._rho_to_pixels(pts, n, rho, valid)

    def _rho_to_pixels(self, pts: np.ndarray, n: np.ndarray, rho: np.ndarray,
                       valid: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(n > 0, rho / n, 0.0)
        u = pts[:, 1] * scale  # x_ocam = y_probe (row direction)
        v = pts[:, 0] * scale  # y_ocam = x_probe (column direction)
        row = self.c * u + self.d * v + self.center_row
        col = self.e * u + v + self.center_col
        out = np.stack([col, row], axis=1)
        out[~valid] = np.nan
        return out

    def scaled(self, factor: float) -> OcamModel:
        """The same lens on a sensor resampled by ``factor`` (pixel centres kept)."""
        s = float(factor)
        pol = tuple(a * s ** (1 - i) for i, a in enumerate(self.pol))
        return OcamModel(
            pol=pol,
            invpol=tuple(p * s for p in self.invpol),
            center_row=(self.center_row + 0.5) * s - 0.5,
            center_col=(self.center_col + 0.5) * s - 0.5,
            c=self.c, d=self.d, e=self.e,
            width=round(self.width * s), height=round(self.height * s),
        )


def fit_invpol(model: OcamModel, *, max_error_px: float = 0.01, max_degree: int = 20) -> tuple:
    """Fit OCamCalib's world2cam polynomial rho(t) to the exact inverse of ``pol``.

    Like OCamCalib's ``findinvpoly.m``: increase the degree until the largest error
    over the valid range is below ``max_error_px``.

    Returns
    -------
    tuple of float
        Ascending coefficients of rho(t), t = incidence - pi/2 in radians.
    """
    t = model._theta_table - np.pi / 2
    rho = model._rho_table
    coef = np.zeros(1)
    for degree in range(2, max_degree + 1):
        coef = np.polynomial.polynomial.polyfit(t, rho, degree)
        if np.max(np.abs(np.polynomial.polynomial.polyval(t, coef) - rho)) < max_error_px:
            break
    return tuple(float(v) for v in coef)
