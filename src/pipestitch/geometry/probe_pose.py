"""The probe pose (SPEC) and the probe-to-world transform it defines.

A point p in the probe frame is at ``w = Rz(roll)·(Rx(alpha)·Ry(beta)·p + (dx, dy, 0))
+ (0, 0, z)`` in the pipe (world) frame. alpha, beta, dx, dy are what the laser ring
measures; roll and z come from registration or odometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipestitch.geometry.rotations import rot_x, rot_y, rot_z

__all__ = ["Pose"]


@dataclass(frozen=True, slots=True)
class Pose:
    """Probe pose in the pipe. Angles in radians, lengths in mm.

    Attributes
    ----------
    alpha, beta : float
        Tilt about x, then about y (radians).
    dx_mm, dy_mm : float
        Offset of the camera centre from the pipe axis (before roll).
    roll : float
        Rotation about the pipe axis (radians).
    z_mm : float
        Axial position of the camera centre.
    """

    alpha: float = 0.0
    beta: float = 0.0
    dx_mm: float = 0.0
    dy_mm: float = 0.0
    roll: float = 0.0
    z_mm: float = 0.0

    def __post_init__(self) -> None:
        # math.isfinite per value, no generator: this runs for every pose a fit makes
        finite = math.isfinite
        if not (finite(self.alpha) and finite(self.beta) and finite(self.dx_mm)
                and finite(self.dy_mm) and finite(self.roll) and finite(self.z_mm)):
            values = (self.alpha, self.beta, self.dx_mm, self.dy_mm, self.roll, self.z_mm)
            raise ValueError(f"Pose: expected finite values, got {values}")

    @classmethod
    def from_degrees(cls, alpha_deg: float = 0.0, beta_deg: float = 0.0, dx_mm: float = 0.0,
                     dy_mm: float = 0.0, roll_deg: float = 0.0, z_mm: float = 0.0) -> Pose:
        """Build a pose from angles in degrees (the unit of files and the CLI)."""
        return cls(np.deg2rad(alpha_deg), np.deg2rad(beta_deg), dx_mm, dy_mm,
                   np.deg2rad(roll_deg), z_mm)

    @property
    def tilt(self) -> float:
        """Angle between the optical axis and the pipe axis (radians)."""
        return float(np.arccos(np.clip(self.rotation_world_probe()[2, 2], -1.0, 1.0)))

    def rotation_world_probe(self) -> np.ndarray:
        """R_world_probe = Rz(roll)·Rx(alpha)·Ry(beta)."""
        return rot_z(self.roll) @ rot_x(self.alpha) @ rot_y(self.beta)

    def translation_world_probe(self) -> np.ndarray:
        """Position of the camera centre in the world: Rz(roll)·(dx, dy, 0) + (0, 0, z)."""
        return rot_z(self.roll) @ np.array([self.dx_mm, self.dy_mm, 0.0]) + [0.0, 0.0, self.z_mm]

    def to_world(self, points_probe: np.ndarray) -> np.ndarray:
        """Map probe-frame points (N, 3) into the world frame."""
        pts = np.asarray(points_probe, dtype=np.float64)
        return pts @ self.rotation_world_probe().T + self.translation_world_probe()

    def to_probe(self, points_world: np.ndarray) -> np.ndarray:
        """Map world points (N, 3) into the probe frame (inverse of :meth:`to_world`)."""
        pts = np.asarray(points_world, dtype=np.float64)
        return (pts - self.translation_world_probe()) @ self.rotation_world_probe()

    def directions_to_world(self, dirs_probe: np.ndarray) -> np.ndarray:
        """Rotate probe-frame directions (N, 3) into the world frame."""
        return np.asarray(dirs_probe) @ self.rotation_world_probe().T

    def as_degrees(self) -> dict[str, float]:
        """The pose with SPEC's column names and units (degrees, mm)."""
        return {"alpha_deg": float(np.rad2deg(self.alpha)),
                "beta_deg": float(np.rad2deg(self.beta)),
                "dx_mm": float(self.dx_mm), "dy_mm": float(self.dy_mm),
                "z_mm": float(self.z_mm), "roll_deg": float(np.rad2deg(self.roll))}
