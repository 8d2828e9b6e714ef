"""Common interface of the camera models and the numerics they share.

A camera model maps points in the SPEC probe frame (x towards increasing column,
y towards increasing row, z forward along the optical axis, mm) to pixels
(col, row), 0-based with pixel centres at integers, and back to unit rays.

Fisheye lenses here see more than a hemisphere (~185°), so every model is written
in terms of the incidence angle ``theta = atan2(sqrt(x² + y²), z)`` measured from
the optical axis. That angle is well defined for rays behind the image plane
(theta > 90°), unlike the pinhole-style normalisation by ``z`` (``tan theta``)
that breaks at 90°. Outside its valid range a model returns NaN, never garbage.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "CameraModel",
    "as_points",
    "invert_monotonic",
    "pixel_grid",
    "rays_from_angles",
]


@runtime_checkable
class CameraModel(Protocol):
    """What every camera model offers (see the module docstring for frames)."""

    width: int
    height: int

    @property
    def max_incidence_rad(self) -> float:
        """Largest incidence angle (from the optical axis) the model is valid for."""

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) probe-frame points -> (N, 2) pixels (col, row); NaN where invalid."""

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """(N, 2) pixels (col, row) -> (N, 3) unit rays; NaN where invalid."""

    def scaled(self, factor: float) -> CameraModel:
        """The same lens on a sensor resampled by ``factor`` (0.5 = half size)."""


def as_points(points: np.ndarray, ncols: int, name: str) -> np.ndarray:
    """Check and convert an (N, ncols) array to float64.

    Parameters
    ----------
    points : array_like, shape (N, ncols) or (ncols,)
        Input points.
    ncols : int
        Expected number of columns (2 for pixels, 3 for points).
    name : str
        Argument name for the error message.

    Returns
    -------
    numpy.ndarray, shape (N, ncols), float64
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != ncols:
        raise ValueError(f"{name}: expected shape (N, {ncols}), got {np.shape(points)}")
    return arr


def rays_from_angles(theta: np.ndarray, cos_phi: np.ndarray, sin_phi: np.ndarray) -> np.ndarray:
    """Unit rays from incidence angle ``theta`` and image azimuth (cos, sin).

    The azimuth is the direction of the pixel offset from the image centre in
    (x = column, y = row) terms.
    """
    s = np.sin(theta)
    return np.stack([s * cos_phi, s * sin_phi, np.cos(theta)], axis=-1)


def invert_monotonic(
    func: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    target: np.ndarray,
    grid_x: np.ndarray,
    grid_y: np.ndarray,
    *,
    iterations: int = 6,
) -> np.ndarray:
    """Solve ``func(x) = target`` for a monotonic increasing scalar function.

    A lookup table (``grid_x`` -> ``grid_y``, sampled once when the model is built)
    gives the starting point and Newton's method polishes it to machine precision.
    This is the exact inverse the models use instead of a fitted inverse
    polynomial, whose error (OCamCalib fits ``invpol`` to ~0.01 px) is far above
    the 1e-6 px round trip we require.

    Parameters
    ----------
    func : callable
        ``func(x) -> (value, derivative)``, vectorised.
    target : numpy.ndarray
        Values to invert; must lie inside ``[grid_y[0], grid_y[-1]]``.
    grid_x, grid_y : numpy.ndarray
        Increasing samples of the function over its valid domain.
    iterations : int
        At most this many Newton steps (quadratic convergence: 6 is ample from a
        dense table); stops early once every step is below 1e-13 of the domain.

    Returns
    -------
    numpy.ndarray
        ``x`` with ``func(x) = target``, clipped to the valid domain.
    """
    x = np.interp(target, grid_y, grid_x)
    lo, hi = grid_x[0], grid_x[-1]
    tol = 1e-13 * max(abs(lo), abs(hi), 1.0)
    for _ in range(iterations):
        value, slope = func(x)
        step = (value - target) / slope
        x = np.clip(x - step, lo, hi)
        if step.size == 0 or float(np.max(np.abs(step))) <= tol:
            break  # converged (quadratically): usually after 2 steps from the table
    return x


def pixel_grid(width: int, height: int) -> np.ndarray:
    """All pixel centres of a ``width`` × ``height`` image as (H·W, 2) (col, row)."""
    cols, rows = np.meshgrid(np.arange(width, dtype=np.float64),
                             np.arange(height, dtype=np.float64))
    return np.stack([cols.ravel(), rows.ravel()], axis=1)
