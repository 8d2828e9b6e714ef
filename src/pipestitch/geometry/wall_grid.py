"""The pixel grid of an unrolled pipe wall.

An *unrolled wall image* stores the wall albedo (reflectance, 0 = black, 1 = white)
on a regular grid in cylinder coordinates (SPEC convention): the centre of pixel
(row ``i``, column ``j``) lies at circumferential angle ``theta = i * deg_per_px``
(degrees, ``[0, 360)``) and axial position ``z = z0_mm + j * mm_per_px_axial``. One
row step is an arc of ``radius_mm * deg2rad(deg_per_px)`` mm on the wall. Rows wrap
around (row ``n_rows`` is row 0 again), and every texture of
:mod:`pipestitch.simulate.textures` is seamless across that wrap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["WallGrid"]


@dataclass(frozen=True)
class WallGrid:
    """Pixel grid of an unrolled pipe wall (see the module docstring).

    Parameters
    ----------
    radius_mm : float
        Wall radius (mm).
    mm_per_px_axial : float
        Axial pixel pitch (mm per column).
    deg_per_px : float
        Circumferential pixel pitch (degrees per row); ``360 / deg_per_px`` must be
        an integer (to 1e-6), so that the rows close up around the pipe.
    z0_mm : float
        Axial position of the centre of column 0 (mm).
    n_cols : int
        Number of columns.

    Raises
    ------
    ValueError
        On a non-positive pitch, radius or column count, or when ``360 / deg_per_px``
        is not an integer.
    """

    radius_mm: float
    mm_per_px_axial: float
    deg_per_px: float
    z0_mm: float
    n_cols: int

    def __post_init__(self) -> None:
        for name in ("radius_mm", "mm_per_px_axial", "deg_per_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"WallGrid.{name}: expected a positive number, got {value!r}")
        if not math.isfinite(self.z0_mm):
            raise ValueError(f"WallGrid.z0_mm: expected a finite number, got {self.z0_mm!r}")
        if int(self.n_cols) != self.n_cols or self.n_cols < 1:
            raise ValueError(f"WallGrid.n_cols: expected a positive integer, got {self.n_cols!r}")
        for name in ("radius_mm", "mm_per_px_axial", "deg_per_px", "z0_mm"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "n_cols", int(self.n_cols))
        self.check_deg_per_px(self.deg_per_px)

    @classmethod
    def check_deg_per_px(cls, deg_per_px: float) -> int:
        """Validate a circumferential pitch and return the row count it implies.

        Parameters
        ----------
        deg_per_px : float
            Degrees per row.

        Returns
        -------
        int
            ``round(360 / deg_per_px)``.

        Raises
        ------
        ValueError
            When ``360 / deg_per_px`` is not within 1e-6 of a positive integer.
        """
        ratio = 360.0 / deg_per_px
        n = round(ratio)
        if n < 1 or abs(ratio - n) > 1e-6:
            raise ValueError(
                f"WallGrid.deg_per_px: 360 / {deg_per_px!r} = {ratio!r} is not an integer; "
                "the rows must close up around the pipe")
        return int(n)

    @property
    def n_rows(self) -> int:
        """Number of rows, ``round(360 / deg_per_px)`` (one full turn)."""
        return round(360.0 / self.deg_per_px)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)``, the shape of an albedo image on this grid."""
        return self.n_rows, int(self.n_cols)

    @property
    def circumference_mm(self) -> float:
        """Wall circumference ``2 pi radius`` (mm)."""
        return 2.0 * math.pi * self.radius_mm

    @property
    def mm_per_px_circ(self) -> float:
        """Arc length of one row step on the wall (mm)."""
        return self.radius_mm * math.radians(self.deg_per_px)

    @property
    def length_mm(self) -> float:
        """Axial extent covered by the columns, ``n_cols * mm_per_px_axial`` (mm)."""
        return self.n_cols * self.mm_per_px_axial

    @classmethod
    def square(cls, radius_mm: float, mm_per_px: float, z0_mm: float,
               z1_mm: float) -> WallGrid:
        """Grid with (nearly) square pixels of ``mm_per_px`` on the wall.

        Parameters
        ----------
        radius_mm : float
            Wall radius (mm).
        mm_per_px : float
            Wanted pixel pitch on the wall, axially and around (mm).
        z0_mm, z1_mm : float
            Axial positions of the first and (about) the last column centre (mm),
            ``z1_mm > z0_mm``.

        Returns
        -------
        WallGrid
            ``mm_per_px_axial = mm_per_px``; ``deg_per_px = 360 / n_rows`` with
            ``n_rows = round(2 pi radius / mm_per_px)``, so the arc pitch is within
            half a row per turn of ``mm_per_px``; ``n_cols = round((z1 - z0) /
            mm_per_px) + 1``.
        """
        if not (radius_mm > 0 and mm_per_px > 0):
            raise ValueError("WallGrid.square: radius_mm and mm_per_px must be positive")
        if not z1_mm > z0_mm:
            raise ValueError(f"WallGrid.square: need z1_mm > z0_mm, got {z0_mm}, {z1_mm}")
        n_rows = max(3, round(2.0 * math.pi * radius_mm / mm_per_px))
        n_cols = round((z1_mm - z0_mm) / mm_per_px) + 1
        return cls(float(radius_mm), float(mm_per_px), 360.0 / n_rows, float(z0_mm), n_cols)

    def theta_z(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates.

        Returns
        -------
        theta_deg : numpy.ndarray, shape (n_rows,), float64
            Angle of each row (degrees, ``[0, 360)``).
        z_mm : numpy.ndarray, shape (n_cols,), float64
            Axial position of each column (mm).
        """
        theta = np.arange(self.n_rows, dtype=np.float64) * self.deg_per_px
        z = self.z0_mm + np.arange(self.n_cols, dtype=np.float64) * self.mm_per_px_axial
        return theta, z

    def to_json(self) -> dict[str, float]:
        """The SPEC wall-image metadata (``n_cols`` is the image width, not stored).

        Returns
        -------
        dict
            ``{"mm_per_px_axial", "deg_per_px", "z0_mm", "radius_mm"}`` as floats.
        """
        return {"mm_per_px_axial": float(self.mm_per_px_axial),
                "deg_per_px": float(self.deg_per_px),
                "z0_mm": float(self.z0_mm),
                "radius_mm": float(self.radius_mm)}
