"""Scaramuzza / OCamCalib omnidirectional camera model (pure maths, no file reading).

Conventions follow OCamCalib's ``calib_results.txt`` exactly (see SPEC and
``docs/conventions.md``): ``pol`` is the cam2world polynomial F(rho) in ascending
powers of rho (pixels), ``invpol`` the fitted world2cam polynomial rho(t) with
t = atan(z / sqrt(x² + y²)), ``center`` is (row, column) 0-based and the affine
part maps ``[row - xc, col - yc] = [[c, d], [e, 1]] [u, v]``. OCamCalib's own frame
has x along rows, y along columns and z backwards; the SPEC probe frame is
(x_probe, y_probe, z_probe) = (y_ocam, x_ocam, -z_ocam).

``project`` does not use ``invpol``: it inverts ``pol`` exactly (lookup table +
Newton), so that project and unproject agree to float64 rounding (~1e-12 px) over
the whole image circle, including rays more than 90° off the axis. The per-point
loops of both directions are compiled (numba): the unwrapping projects ~10⁵ wall
points per strip, and as array expressions the table look-up and the Newton steps
cost ~100 ns a point; the pose fit unprojects ~1,700 ring points a frame, where a
dozen array expressions' fixed costs outweighed the arithmetic. ``invpol``
is kept for export and for comparison with other tools
(:meth:`OcamModel.project_invpol`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)
from pipestitch.camera.base import OCAM, RayKernel, as_points

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
    _theta_start: np.ndarray = field(init=False, repr=False, compare=False)
    _pol_array: np.ndarray = field(init=False, repr=False, compare=False)
    _dpol_array: np.ndarray = field(init=False, repr=False, compare=False)
    _affine_array: np.ndarray = field(init=False, repr=False, compare=False)
    _ray_kernel: RayKernel = field(init=False, repr=False, compare=False)

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
        # the kernels' arguments: pol and (c, d, e, center_row, center_col)
        object.__setattr__(self, "_pol_array", np.array(pol))
        object.__setattr__(self, "_dpol_array", np.polynomial.polynomial.polyder(self._pol_array))
        object.__setattr__(self, "_affine_array", np.array(
            [self.c, self.d, self.e, self.center_row, self.center_col], dtype=np.float64))
        rho, theta = self._monotonic_table()
        object.__setattr__(self, "_rho_table", rho)
        object.__setattr__(self, "_theta_table", theta)
        # Where to start searching the table for an angle: the table entry at or below
        # each of theta.size equal steps of the angle (the table is nearly uniform in
        # theta, so the search from there is a step or two).
        steps = np.arange(theta.size + 1) * (theta[-1] / theta.size)
        start = np.searchsorted(theta, steps, side="right") - 1
        object.__setattr__(self, "_theta_start", np.clip(start, 0, theta.size - 2))
        object.__setattr__(self, "_ray_kernel", RayKernel(
            OCAM, self._pol_array, self._affine_array, rho[-1:].copy(), np.empty(0),
            np.empty(0, np.int64)))

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

    @property
    def ray_kernel(self) -> RayKernel:
        """:meth:`unproject`'s compiled loop as data (for ``camera.kernels.rays_of``)."""
        return self._ray_kernel

    # --- projection ----------------------------------------------------------------
    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) as (col, row) -> unit rays (N, 3) in the SPEC probe frame.

        Pixels outside the valid image circle give NaN rays.
        """
        px = np.ascontiguousarray(as_points(pixels, 2, "pixels"))
        return ray_loop(px, self._pol_array, self._affine_array, float(self._rho_table[-1]))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Probe-frame points (N, 3) -> pixels (N, 2) as (col, row).

        Exact inverse of :meth:`unproject` (Newton on theta(rho)); NaN for points
        beyond the valid incidence angle, at the origin or non-finite.
        """
        pts = np.ascontiguousarray(as_points(points, 3, "points"))
        rho = _rho_of_points(pts, self._pol_array, self._dpol_array, self._rho_table,
                             self._theta_table, self._theta_start)
        return self._rho_to_pixels(pts, rho)

    def project_invpol(self, points: np.ndarray) -> np.ndarray:
        """Project with the fitted ``invpol`` as OCamCalib's C ``world2cam`` does.

        Accurate only to the fit (~0.01 px); for comparison with other tools.
        """
        if not self.invpol:
            raise ValueError("ocam: this model has no invpol")
        pts = np.ascontiguousarray(as_points(points, 3, "points"))
        n = np.hypot(pts[:, 0], pts[:, 1])
        t = np.arctan2(-pts[:, 2], n)  # OCamCalib: atan(z_ocam / n), z_ocam = -z_probe
        rho = np.polynomial.polynomial.polyval(t, self.invpol)
        valid = np.arctan2(n, pts[:, 2]) <= self.max_incidence_rad
        return self._rho_to_pixels(pts, np.where(valid, rho, np.nan))

    def _rho_to_pixels(self, pts: np.ndarray, rho: np.ndarray) -> np.ndarray:
        return _pixels(pts, rho, self._affine_array)

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


@numba.njit(cache=True, nogil=True)
def _rho_of_points(pts: np.ndarray, pol: np.ndarray, dpol: np.ndarray, rho_table: np.ndarray,
                   theta_table: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Image radius rho (pre-affine px) of each probe-frame point; NaN where invalid.

    Invalid: beyond the table's largest incidence angle, at the origin, or not finite.
    The incidence angle is looked up in the table (``start`` indexes it by equal
    angle steps) and rho polished by Newton on n·F(rho) + z·rho = 0 (the ray through
    (rho, F(rho)) in OCamCalib's frame passes through the point; n = sqrt(x² + y²)),
    clipped to the table's range, until a step is below 1e-13 of that range (at most
    6 steps; 1 or 2 from the table).
    """
    out = np.empty(pts.shape[0])
    lo, hi, last = rho_table[0], rho_table[-1], theta_table.shape[0] - 2
    tol = 1e-13 * max(abs(lo), abs(hi), 1.0)
    inv_step = (start.shape[0] - 1) / theta_table[-1]
    for k in range(pts.shape[0]):
        x, y, z = pts[k, 0], pts[k, 1], pts[k, 2]
        n = math.hypot(x, y)
        theta = math.atan2(n, z)
        if not (theta <= theta_table[-1] and (n > 0 or z != 0)):
            out[k] = np.nan
            continue
        j = start[min(int(theta * inv_step), start.shape[0] - 1)]
        while j < last and theta_table[j + 1] <= theta:
            j += 1
        rho = rho_table[j] + ((rho_table[j + 1] - rho_table[j]) * (theta - theta_table[j])
                              / (theta_table[j + 1] - theta_table[j]))
        for _ in range(6):
            f, df = _horner(pol, rho), _horner(dpol, rho)
            step = (n * f + z * rho) / (n * df + z)
            rho = min(max(rho - step, lo), hi)
            if abs(step) <= tol:
                break
        out[k] = rho
    return out


# Float options as ``ray_loop``'s, set here: a kernel without them takes those of whichever
# caller compiles it first (``ray_loop`` or ``_rho_of_points``), and its bits with them
# (docs/conventions.md, "Compiled kernels")
@numba.njit(cache=True, nogil=True, error_model="numpy",
            fastmath={"reassoc", "contract", "arcp"})
def _horner(coef: np.ndarray, x: float) -> float:
    """Polynomial with ascending coefficients at x (as numpy's ``polyval`` sums it)."""
    f = coef[-1]
    for i in range(coef.shape[0] - 2, -1, -1):
        f = coef[i] + f * x
    return f


# reassociation and contraction only (NaN and inf keep their meaning: the NaN tests below)
@numba.njit(cache=True, nogil=True, error_model="numpy",
            fastmath={"reassoc", "contract", "arcp"})
def ray_loop(pixels: np.ndarray, pol: np.ndarray, affine: np.ndarray, max_rho: float) -> np.ndarray:
    """Unit rays (SPEC probe frame) of pixels (col, row); NaN beyond ``max_rho`` or NaN.

    ``affine`` is (c, d, e, center_row, center_col). The ray in OCamCalib's frame is
    (u, v, F(rho)) for the pre-affine offset (u, v) along (row, column), rho = |(u, v)|;
    in the probe frame (v, u, -F(rho)), normalised. Compiled because the pose of a frame
    unprojects ~1,700 points, and as a dozen array expressions that took as long as
    the rest of the fit (no library has the OCamCalib model with the SPEC frame).
    """
    c, d, e, center_row, center_col = affine[0], affine[1], affine[2], affine[3], affine[4]
    invdet = 1.0 / (c - d * e)
    out = np.empty((pixels.shape[0], 3))
    for k in range(pixels.shape[0]):
        dr, dc = pixels[k, 1] - center_row, pixels[k, 0] - center_col
        u = invdet * (dr - d * dc)
        v = invdet * (-e * dr + c * dc)
        rho2 = u * u + v * v
        if not rho2 <= max_rho * max_rho:
            out[k, 0] = out[k, 1] = out[k, 2] = np.nan
            continue
        z = -_horner(pol, math.sqrt(rho2))
        inv_norm = 1.0 / math.sqrt(rho2 + z * z)
        out[k, 0], out[k, 1], out[k, 2] = v * inv_norm, u * inv_norm, z * inv_norm
    return out


@numba.njit(cache=True, nogil=True)
def _pixels(pts: np.ndarray, rho: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """Pixels (col, row) of points at image radius ``rho`` (NaN where rho is NaN).

    ``affine`` is (c, d, e, center_row, center_col). One pass instead of the dozen
    array expressions it replaces (they cost as much as the projection itself).
    """
    c, d, e, center_row, center_col = affine[0], affine[1], affine[2], affine[3], affine[4]
    out = np.empty((pts.shape[0], 2))
    for k in range(pts.shape[0]):
        if np.isnan(rho[k]):
            out[k, 0] = out[k, 1] = np.nan
            continue
        n = math.hypot(pts[k, 0], pts[k, 1])
        scale = rho[k] / n if n > 0 else 0.0
        u = pts[k, 1] * scale  # x_ocam = y_probe (row direction)
        v = pts[k, 0] * scale  # y_ocam = x_probe (column direction)
        out[k, 0] = e * u + v + center_col
        out[k, 1] = c * u + d * v + center_row
    return out


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
