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

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "OCAM",
    "OPENCV_FISHEYE",
    "CameraModel",
    "RayKernel",
    "as_points",
    "pixel_grid",
]

OCAM, OPENCV_FISHEYE = 1, 2   # RayKernel.kind of each model


class RayKernel(NamedTuple):
    """A model's compiled unprojection as data (:func:`pipestitch.camera.kernels.rays_of`).

    ``kind`` names the model (:data:`OCAM`, :data:`OPENCV_FISHEYE`); ``a`` … ``d`` and
    ``index`` are its loop's parameter arrays in that loop's order (float64, and int64
    for ``index``; unused ones empty; a scalar parameter is a one-element array, as
    OCam's largest image radius in ``c``). Models offer it as ``ray_kernel``; a model
    without one is unprojected through ``unproject`` only.
    """

    kind: int
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    index: np.ndarray


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


def pixel_grid(width: int, height: int) -> np.ndarray:
    """All pixel centres of a ``width`` × ``height`` image as (H·W, 2) (col, row)."""
    cols, rows = np.meshgrid(np.arange(width, dtype=np.float64),
                             np.arange(height, dtype=np.float64))
    return np.stack([cols.ravel(), rows.ravel()], axis=1)
