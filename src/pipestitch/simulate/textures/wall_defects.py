"""Defects drawn on a wall: holes and stains as true circles in millimetres on
the cylinder, antialiased analytically, and the 7-hole reference test piece.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pipestitch.geometry import WallGrid
from pipestitch.simulate.textures._texture_common import ramp_width

__all__ = ["DEFECT_KINDS", "HOLE_ALBEDO", "SPOT_FACTOR", "SPOT_SOFT_FRACTION", "Defect",
           "draw_defects", "reference_test_piece"]

DEFECT_KINDS = ("hole", "spot")

HOLE_ALBEDO = 0.02          # albedo inside a hole (almost black)
SPOT_FACTOR = 0.45          # a spot multiplies the albedo by this at its centre
SPOT_SOFT_FRACTION = 0.12   # width of a spot's edge ramp, as a fraction of its diameter


@dataclass(frozen=True)
class Defect:
    """A circular defect on the wall.

    Parameters
    ----------
    kind : {"hole", "spot"}
        ``"hole"``: a through hole, drawn almost black (albedo 0.02) with a sharp
        edge; ``"spot"``: a stain that multiplies the albedo by 0.45, with a
        slightly soft edge.
    z_mm : float
        Axial position of the centre (mm).
    theta_deg : float
        Angle of the centre (degrees; any value, taken modulo 360).
    diameter_mm : float
        Diameter on the wall (mm), measured along the surface.
    """

    kind: str
    z_mm: float
    theta_deg: float
    diameter_mm: float

    def __post_init__(self) -> None:
        if self.kind not in DEFECT_KINDS:
            raise ValueError(f"Defect.kind: expected one of {DEFECT_KINDS}, got {self.kind!r}")
        if not (math.isfinite(self.z_mm) and math.isfinite(self.theta_deg)):
            raise ValueError("Defect: z_mm and theta_deg must be finite")
        if not (math.isfinite(self.diameter_mm) and self.diameter_mm > 0):
            raise ValueError(f"Defect.diameter_mm: expected > 0, got {self.diameter_mm!r}")


def _draw_defects_inplace(out: np.ndarray, grid: WallGrid, defects: Iterable[Defect]) -> None:
    n_rows, n_cols = grid.shape
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    r_wall = grid.radius_mm
    theta, z = grid.theta_z()
    for d in defects:
        radius = 0.5 * d.diameter_mm
        soft = SPOT_SOFT_FRACTION * d.diameter_mm if d.kind == "spot" else 0.0
        ext = radius + 0.5 * math.hypot(max(ws, wz), soft) + max(ws, wz)
        tc = d.theta_deg % 360.0
        sc = r_wall * math.radians(tc)
        i_lo, i_hi = math.floor((sc - ext) / ws), math.ceil((sc + ext) / ws)
        if i_hi - i_lo + 1 >= n_rows:
            rows = np.arange(n_rows)
        else:
            rows = np.arange(i_lo, i_hi + 1) % n_rows
        j_lo = max(0, math.floor((d.z_mm - ext - grid.z0_mm) / wz))
        j_hi = min(n_cols - 1, math.ceil((d.z_mm + ext - grid.z0_mm) / wz))
        if j_hi < j_lo:
            continue
        dth = (theta[rows] - tc + 180.0) % 360.0 - 180.0
        ds = (r_wall * np.radians(dth))[:, None]
        dz = (z[j_lo:j_hi + 1] - d.z_mm)[None, :]
        dist = np.hypot(ds, dz)
        w = ramp_width(ds, dz, dist, ws, wz)
        if soft:
            w = np.hypot(w, soft)
        cov = np.clip(0.5 - (dist - radius) / w, 0.0, 1.0).astype(np.float32)
        if rows[0] <= rows[-1] and len(rows) == rows[-1] - rows[0] + 1:
            idx: tuple = (slice(int(rows[0]), int(rows[-1]) + 1), slice(j_lo, j_hi + 1))
        else:
            idx = np.ix_(rows, np.arange(j_lo, j_hi + 1))
        blk = out[idx]
        if d.kind == "hole":
            blk += cov * (np.float32(HOLE_ALBEDO) - blk)
        else:
            blk *= 1.0 - np.float32(1.0 - SPOT_FACTOR) * cov
        out[idx] = blk


def draw_defects(albedo: np.ndarray, grid: WallGrid, defects: Iterable[Defect]) -> np.ndarray:
    """Draw holes and spots, as true circles on the cylinder, onto a copy of ``albedo``.

    The distance from a pixel centre to a defect centre is measured on the wall,
    ``sqrt((radius * dtheta_rad)^2 + dz^2)`` with ``dtheta`` wrapped to
    [-180, 180) degrees, so a defect across theta = 0 is drawn whole. Coverage is
    computed analytically from the signed distance ``d`` to the rim,
    ``clip(0.5 - d / w, 0, 1)`` with ``w`` the pixel's extent across the rim (the
    pixel pitch for square pixels): sub-pixel antialiasing that keeps the area (to
    O(w^2)) and the centre, no blurring. A hole sets the albedo to 0.02
    (``out += cov * (0.02 - out)``); a spot multiplies it by ``1 - 0.55 * cov``
    with its ramp widened to ``hypot(w, 0.12 * diameter)`` (a soft edge still
    centred on the nominal rim). Defects are drawn in order.

    Parameters
    ----------
    albedo : numpy.ndarray, shape grid.shape
        Wall albedo (not modified).
    grid : WallGrid
        Grid of ``albedo``.
    defects : iterable of Defect
        What to draw.

    Returns
    -------
    numpy.ndarray, shape grid.shape, float32
        A new albedo image.
    """
    arr = np.asarray(albedo)
    if arr.shape != grid.shape:
        raise ValueError(f"albedo: shape {arr.shape} does not match the grid {grid.shape}")
    out = np.array(arr, dtype=np.float32, copy=True)
    _draw_defects_inplace(out, grid, defects)
    return out


def reference_test_piece(z_centre_mm: float, theta_centre_deg: float = 90.0,
                         pitch_mm: float = 24.0, diameter_mm: float = 6.0, *,
                         radius_mm: float) -> list[Defect]:
    """The reference test piece: 7 holes in a cross.

    Holes of ``diameter_mm`` at the centre, at +-pitch and +-2 pitch along z, and at
    +-pitch of arc length around the circumference (converted to degrees with
    ``radius_mm``).

    Parameters
    ----------
    z_centre_mm : float
        Axial position of the centre hole (mm).
    theta_centre_deg : float
        Angle of the centre hole (degrees).
    pitch_mm : float
        Hole spacing, axially and as arc length around (mm).
    diameter_mm : float
        Hole diameter (mm).
    radius_mm : float
        Wall radius (mm), keyword-only.

    Returns
    -------
    list of Defect
        In this order: centre; z - 2p, z - p, z + p, z + 2p; arc - p, arc + p
        (angles in [0, 360)).
    """
    if not (radius_mm > 0 and pitch_mm > 0 and diameter_mm > 0):
        raise ValueError("reference_test_piece: radius_mm, pitch_mm and diameter_mm must be > 0")
    dth = math.degrees(pitch_mm / radius_mm)
    t0 = theta_centre_deg % 360.0
    offsets = [(0.0, 0.0), (-2.0, 0.0), (-1.0, 0.0), (1.0, 0.0), (2.0, 0.0),
               (0.0, -1.0), (0.0, 1.0)]
    return [Defect("hole", float(z_centre_mm + kz * pitch_mm), float((t0 + kt * dth) % 360.0),
                   float(diameter_mm)) for kz, kt in offsets]
