"""Centralised unwrapping: an LED frame + its pose -> a strip of the wall in (theta, z).

For every node of an output grid over the wall (theta around the pipe, z along it,
relative to the camera's axial position and with roll 0) the wall point is moved
into the probe frame by the frame's pose, projected by the camera model and the
frame is sampled there with ``cv2.remap``: one resampling, straight from wall to
pixel, so the strip has a true millimetre scale whatever the probe's tilt and
offset. Nodes outside the lens' valid range or the image are masked (NaN); occluders
inside the image (mirror assembly, laser-holder arm) are not known from probe.toml
and are left to the caller (see :mod:`pipestitch.photometric`).

This module is the geometric core; choosing windows from the field of view,
quality weights and the mosaic belong to the mosaic stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose

__all__ = ["StripGrid", "unwrap", "unwrap_maps"]


@dataclass(frozen=True)
class StripGrid:
    """Output grid: row i at theta = i·deg_per_px, column j at z = z0_mm + j·mm_per_px.

    z is measured from the camera centre along the pipe axis.
    """

    deg_per_px: float
    mm_per_px: float
    z0_mm: float
    n_cols: int

    def __post_init__(self) -> None:
        n = 360.0 / self.deg_per_px
        if abs(n - round(n)) > 1e-6 or self.mm_per_px <= 0 or self.n_cols < 1:
            raise ValueError(f"StripGrid: 360/deg_per_px must be an integer and sizes positive, "
                             f"got {self}")

    @property
    def n_rows(self) -> int:
        """Rows around the full circumference."""
        return round(360.0 / self.deg_per_px)

    @classmethod
    def window(cls, radius_mm: float, mm_per_px: float, z0_mm: float, z1_mm: float) -> StripGrid:
        """Square pixels in mm on the wall (arc length = axial step) from z0 to z1."""
        n_rows = max(8, round(2 * np.pi * radius_mm / mm_per_px))
        return cls(360.0 / n_rows, mm_per_px, z0_mm, max(1, round((z1_mm - z0_mm) / mm_per_px)))


def unwrap_maps(camera: CameraModel, pose: Pose, section: PipeSection,
                grid: StripGrid) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` maps (float32, (n_rows, n_cols)) from the strip to the frame.

    Invisible nodes get -1 (outside the image), so remap returns the border value.
    """
    theta = np.deg2rad(np.arange(grid.n_rows) * grid.deg_per_px)
    z = grid.z0_mm + np.arange(grid.n_cols) * grid.mm_per_px
    th, zz = np.meshgrid(theta, z, indexing="ij")
    wall = section.points(th.ravel(), zz.ravel())
    # Roll and axial position are those of the strip's own frame: zero by construction.
    local = Pose(pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm)
    px = camera.project(local.to_probe(wall))
    px[~np.isfinite(px).all(axis=1)] = -1.0
    shape = (grid.n_rows, grid.n_cols)
    return px[:, 0].reshape(shape).astype(np.float32), px[:, 1].reshape(shape).astype(np.float32)


def unwrap(frame: np.ndarray, camera: CameraModel, pose: Pose, section: PipeSection,
           grid: StripGrid) -> np.ndarray:
    """Resample ``frame`` (grey float32) onto the wall grid; masked nodes are NaN."""
    map_x, map_y = unwrap_maps(camera, pose, section, grid)
    strip = cv2.remap(frame, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=np.nan)
    strip[map_x < 0] = np.nan
    return strip
