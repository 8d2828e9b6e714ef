"""Pipe cross-sections (circular or oval) and wall point <-> (theta, z).

The pipe axis is the world z axis. A cross-section is an ellipse centred on the
axis with semi-axes ``a_mm`` (along the direction ``angle`` from world x) and
``b_mm``; a circle has ``a_mm == b_mm``. theta = atan2(y, x) in radians, [0, 2pi).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PipeSection", "RadiusProfile", "theta_z_from_points"]


@dataclass(frozen=True, eq=False)
class RadiusProfile:
    """A wall whose section changes size along the pipe (a reducer, a long dent): the
    section is scaled about the axis by ``scale`` at axial positions ``z_mm``,
    linearly in between and held at the end values beyond them.

    Attributes
    ----------
    z_mm : numpy.ndarray
        Increasing axial positions (mm; world z, or a frame's own z where a caller says).
    scale : numpy.ndarray
        Wall radius there over the section's (1: the section itself).
    """

    z_mm: np.ndarray
    scale: np.ndarray

    def __post_init__(self) -> None:
        z, s = np.asarray(self.z_mm, float), np.asarray(self.scale, float)
        if (z.ndim != 1 or z.shape != s.shape or z.size == 0 or not np.all(np.isfinite(z))
                or not np.all(np.isfinite(s)) or np.any(s <= 0) or np.any(np.diff(z) <= 0)):
            raise ValueError("RadiusProfile: expected increasing finite z and positive "
                             f"scales of one length, got {z!r}, {s!r}")
        object.__setattr__(self, "z_mm", z)
        object.__setattr__(self, "scale", s)

    def at(self, z_mm: np.ndarray | float) -> np.ndarray:
        """The scale at ``z_mm``."""
        return np.interp(z_mm, self.z_mm, self.scale)

    def shifted(self, dz_mm: float) -> RadiusProfile:
        """The same wall with z measured from ``dz_mm`` (its z minus ``dz_mm``)."""
        return RadiusProfile(self.z_mm - dz_mm, self.scale)


@dataclass(frozen=True, slots=True)
class PipeSection:
    """Elliptical pipe cross-section (circle when ``a_mm == b_mm``).

    Attributes
    ----------
    a_mm, b_mm : float
        Semi-axes in mm.
    angle : float
        Direction of the ``a`` semi-axis from world x, radians.
    """

    a_mm: float
    b_mm: float | None = None
    angle: float = 0.0

    def __post_init__(self) -> None:
        if self.b_mm is None:
            object.__setattr__(self, "b_mm", self.a_mm)
        if not (np.isfinite(self.a_mm) and np.isfinite(self.b_mm) and np.isfinite(self.angle)):
            raise ValueError(f"PipeSection: expected finite values, got {self}")
        if self.a_mm <= 0 or self.b_mm <= 0:
            raise ValueError(f"PipeSection: semi-axes must be positive, got {self.a_mm}, "
                             f"{self.b_mm}")

    @classmethod
    def circle(cls, diameter_mm: float) -> PipeSection:
        """Circular section of inner diameter ``diameter_mm``."""
        return cls(diameter_mm / 2.0, diameter_mm / 2.0)

    @classmethod
    def oval(cls, diameter_mm: float, ovality: float, angle: float = 0.0) -> PipeSection:
        """Oval of mean diameter ``diameter_mm`` and ovality (Dmax - Dmin)/Dmean (SPEC)."""
        r = diameter_mm / 2.0
        return cls(r * (1 + ovality / 2), r * (1 - ovality / 2), angle)

    @property
    def is_circle(self) -> bool:
        """True when both semi-axes are equal."""
        return bool(self.a_mm == self.b_mm)

    @property
    def mean_radius_mm(self) -> float:
        """(a + b) / 2."""
        return 0.5 * (self.a_mm + self.b_mm)

    @property
    def ovality(self) -> float:
        """(Dmax - Dmin) / Dmean, the SPEC definition, as a fraction."""
        return abs(self.a_mm - self.b_mm) / self.mean_radius_mm

    def metric(self) -> np.ndarray:
        """2 × 2 matrix M with the wall at q^T M q = 1 for q = (x, y)."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        rot = np.array([[c, -s], [s, c]])
        return rot @ np.diag([self.a_mm**-2, self.b_mm**-2]) @ rot.T

    def radius_at(self, theta: np.ndarray) -> np.ndarray:
        """Distance from the axis to the wall at polar angle ``theta`` (rad)."""
        u = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
        return 1.0 / np.sqrt(np.einsum("...i,ij,...j->...", u, self.metric(), u))

    def points(self, theta: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
        """World points (N, 3) on the wall at angles ``theta`` (rad) and ``z_mm``."""
        theta, z_mm = np.broadcast_arrays(np.asarray(theta, float), np.asarray(z_mm, float))
        r = self.radius_at(theta)
        return np.stack([r * np.cos(theta), r * np.sin(theta), z_mm], axis=-1)

    def normals(self, points_world: np.ndarray) -> np.ndarray:
        """Inward-facing unit normals of the wall at world points (N, 3)."""
        (m00, m01), (_, m11) = self.metric()
        pts = np.asarray(points_world)
        gx = -(m00 * pts[..., 0] + m01 * pts[..., 1])
        gy = -(m01 * pts[..., 0] + m11 * pts[..., 1])
        norm = np.sqrt(gx * gx + gy * gy)
        return np.stack([gx / norm, gy / norm, np.zeros_like(gx)], axis=-1)

    def clearance_mm(self, points_world: np.ndarray) -> np.ndarray:
        """Radial distance from world points to the wall: > 0 inside the pipe."""
        pts = np.asarray(points_world)
        theta = np.arctan2(pts[..., 1], pts[..., 0])
        return self.radius_at(theta) - np.hypot(pts[..., 0], pts[..., 1])


def theta_z_from_points(points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) -> (theta in [0, 2pi) radians, z in mm)."""
    pts = np.asarray(points_world)
    theta = np.mod(np.arctan2(pts[..., 1], pts[..., 0]), 2 * np.pi)
    return theta, pts[..., 2]
