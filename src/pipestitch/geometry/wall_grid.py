"""The pixel grid of an image of the pipe wall in cylinder coordinates (theta, z).

The centre of pixel (row ``i``, column ``j``) lies at circumferential angle
``theta = theta0_deg + i * deg_per_px`` (degrees) and axial position
``z = z0_mm + j * mm_per_px_axial`` (mm). The rows always go once around the pipe
(``360 / deg_per_px`` is an integer), so row ``n_rows`` is row 0 again. On a wall of
``radius_mm`` one row step is an arc of ``radius_mm * radians(deg_per_px)`` mm.

The simulator's unrolled wall images (SPEC wall-image convention: ``theta0_deg = 0``,
world z) and the mosaic's strips (z from the camera centre, theta turned by the
frame's roll) and canvas are all images on such a grid. This module only describes
the grid: no image data, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

__all__ = ["WallGrid"]


def _rows_around(radius_mm: float, mm_per_px: float, min_rows: int) -> int:
    """Rows whose arc on a wall of ``radius_mm`` is closest to ``mm_per_px``
    (at least ``min_rows``)."""
    return max(min_rows, round(2.0 * math.pi * radius_mm / mm_per_px))


@dataclass(frozen=True, kw_only=True)
class WallGrid:
    """Pixel grid of an image of the pipe wall (see the module docstring).

    Fields are keyword-only; :meth:`square` and :meth:`window` build grids of square
    pixels on the wall.

    Parameters
    ----------
    radius_mm : float
        Radius of the wall the grid lies on (mm); it turns the angular pitch into an
        arc length.
    deg_per_px : float
        Circumferential pixel pitch (degrees per row); ``360 / deg_per_px`` must be an
        integer (to 1e-6), so that the rows close up around the pipe.
    mm_per_px_axial : float
        Axial pixel pitch (mm per column).
    z0_mm : float
        Axial position of the centre of column 0 (mm).
    n_cols : int
        Number of columns.
    theta0_deg : float, optional
        Angle of the centre of row 0 (degrees, default 0).

    Raises
    ------
    ValueError
        On a non-positive radius, pitch or column count, a non-finite ``z0_mm`` or
        ``theta0_deg``, or when ``360 / deg_per_px`` is not an integer.
    """

    radius_mm: float
    deg_per_px: float
    mm_per_px_axial: float
    z0_mm: float
    n_cols: int
    theta0_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("radius_mm", "deg_per_px", "mm_per_px_axial"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"WallGrid.{name}: expected a positive number, got {value!r}")
        for name in ("z0_mm", "theta0_deg"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"WallGrid.{name}: expected a finite number, got {value!r}")
        if int(self.n_cols) != self.n_cols or self.n_cols < 1:
            raise ValueError(f"WallGrid.n_cols: expected a positive integer, got {self.n_cols!r}")
        object.__setattr__(self, "n_cols", int(self.n_cols))
        ratio = 360.0 / self.deg_per_px
        if not math.isfinite(ratio) or round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                f"WallGrid.deg_per_px: 360 / {self.deg_per_px!r} = {ratio!r} is not an integer; "
                "the rows must close up around the pipe")

    @classmethod
    def square(cls, radius_mm: float, mm_per_px: float, z0_mm: float,
               z1_mm: float) -> WallGrid:
        """Grid with (nearly) square pixels whose columns run from ``z0_mm`` to ``z1_mm``.

        The grid of the simulator's unrolled wall images: the first and (about) the
        last column are centred on the two ends.

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
            ``n_rows = max(3, round(2 pi radius / mm_per_px))``, so the arc pitch is
            within half a row per turn of ``mm_per_px``; ``n_cols = round((z1 - z0) /
            mm_per_px) + 1``; ``theta0_deg = 0``.

        Raises
        ------
        ValueError
            On a non-positive radius or pitch, or when ``z1_mm <= z0_mm``.
        """
        if not (radius_mm > 0 and mm_per_px > 0):
            raise ValueError("WallGrid.square: radius_mm and mm_per_px must be positive")
        if not z1_mm > z0_mm:
            raise ValueError(f"WallGrid.square: need z1_mm > z0_mm, got {z0_mm}, {z1_mm}")
        n_rows = _rows_around(radius_mm, mm_per_px, 3)
        n_cols = round((z1_mm - z0_mm) / mm_per_px) + 1
        return cls(radius_mm=float(radius_mm), deg_per_px=360.0 / n_rows,
                   mm_per_px_axial=float(mm_per_px), z0_mm=float(z0_mm), n_cols=n_cols)

    @classmethod
    def window(cls, radius_mm: float, mm_per_px: float, z0_mm: float, z1_mm: float, *,
               fft_sizes: bool = False) -> WallGrid:
        """Grid with square pixels on the wall (arc = axial step) over the window z0..z1.

        The grid of the mosaic's strips and canvas: ``round((z1 - z0) / mm_per_px)``
        columns from ``z0_mm`` on (at least 1), ``max(8, round(2 pi radius /
        mm_per_px))`` rows, ``theta0_deg = 0``.

        Parameters
        ----------
        radius_mm : float
            Wall radius (mm).
        mm_per_px : float
            Pixel pitch on the wall, axially and around (mm).
        z0_mm, z1_mm : float
            Axial window (mm); column 0 is centred on ``z0_mm``.
        fft_sizes : bool, optional
            Round both sizes up to sizes the FFT is fast for
            (``cv2.getOptimalDFTSize``: products of 2, 3, 5): rows then are slightly
            narrower than the axial step and the window slightly longer. For
            registration strips, whose circular (unpadded) correlation would otherwise
            run on sizes like 1513 = 17 x 89.

        Returns
        -------
        WallGrid
            The grid, ``mm_per_px_axial = mm_per_px``.
        """
        n_rows = _rows_around(radius_mm, mm_per_px, 8)
        n_cols = max(1, round((z1_mm - z0_mm) / mm_per_px))
        if fft_sizes:
            n_rows, n_cols = cv2.getOptimalDFTSize(n_rows), cv2.getOptimalDFTSize(n_cols)
        return cls(radius_mm=radius_mm, deg_per_px=360.0 / n_rows, mm_per_px_axial=mm_per_px,
                   z0_mm=z0_mm, n_cols=n_cols)

    @classmethod
    def from_json(cls, meta: Mapping[str, Any], n_cols: int, *, n_rows: int | None = None,
                  radius_mm: float | None = None) -> WallGrid:
        """The grid of a wall image from its SPEC metadata (the inverse of :meth:`to_json`).

        A pitch written rounded (``0.237938`` for 1513 rows, by another tool) is read as
        the whole number of rows it stands for: ``deg_per_px = 360 / rows``, which is the
        value itself for metadata that :meth:`to_json` wrote.

        Parameters
        ----------
        meta : mapping
            Holds ``mm_per_px_axial``, ``deg_per_px``, ``z0_mm`` and, unless
            ``radius_mm`` is given, ``radius_mm`` (wall.json, mosaic.json and its
            ``full_resolution`` record; other keys are ignored).
        n_cols : int
            The image's width.
        n_rows : int, optional
            The image's height, when it is at hand: the pitch must give that many rows
            (default: ``round(360 / deg_per_px)``).
        radius_mm : float, optional
            Wall radius, for metadata that does not hold it (mosaic.json's
            ``full_resolution``, whose radius is the document's).

        Returns
        -------
        WallGrid
            ``theta0_deg = 0``, as SPEC wall images start at theta 0.

        Raises
        ------
        KeyError
            When ``meta`` lacks a key.
        ValueError
            When the pitch gives no whole number of rows (within a quarter of a row
            around the pipe) or not ``n_rows``, or on values the grid refuses (see
            :class:`WallGrid`).
        """
        deg = float(meta["deg_per_px"])
        if not (deg > 0 and math.isfinite(360.0 / deg)):
            raise ValueError(f"deg_per_px: expected a positive pitch, a finite number of rows "
                             f"around the pipe, got {deg!r}")
        rows = round(360.0 / deg) if n_rows is None else int(n_rows)
        if rows < 1 or abs(rows * deg - 360.0) >= deg / 4:
            raise ValueError(f"deg_per_px {deg!r} does not give {rows} rows around the pipe"
                             if n_rows is not None else
                             f"deg_per_px {deg!r} does not divide 360° into whole rows")
        return cls(radius_mm=float(meta["radius_mm"] if radius_mm is None else radius_mm),
                   deg_per_px=360.0 / rows, mm_per_px_axial=float(meta["mm_per_px_axial"]),
                   z0_mm=float(meta["z0_mm"]), n_cols=n_cols)

    @property
    def n_rows(self) -> int:
        """Number of rows, ``round(360 / deg_per_px)`` (one full turn)."""
        return round(360.0 / self.deg_per_px)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)``, the shape of an image on this grid."""
        return self.n_rows, self.n_cols

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

    def theta_z(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates.

        Returns
        -------
        theta_deg : numpy.ndarray, shape (n_rows,), float64
            Angle of each row (degrees, ``theta0_deg`` + ``[0, 360)``).
        z_mm : numpy.ndarray, shape (n_cols,), float64
            Axial position of each column (mm).
        """
        theta = self.theta0_deg + np.arange(self.n_rows, dtype=np.float64) * self.deg_per_px
        z = self.z0_mm + np.arange(self.n_cols, dtype=np.float64) * self.mm_per_px_axial
        return theta, z

    def to_json(self) -> dict[str, float]:
        """The SPEC wall-image metadata (``n_cols`` is the image width, not stored).

        Returns
        -------
        dict
            ``{"mm_per_px_axial", "deg_per_px", "z0_mm", "radius_mm"}`` as floats.

        Raises
        ------
        ValueError
            When ``theta0_deg`` is not 0: SPEC wall images start at theta 0.
        """
        if self.theta0_deg != 0.0:
            raise ValueError(f"WallGrid.to_json: SPEC wall images start at theta 0, "
                             f"got theta0_deg = {self.theta0_deg!r}")
        return {"mm_per_px_axial": float(self.mm_per_px_axial),
                "deg_per_px": float(self.deg_per_px),
                "z0_mm": float(self.z0_mm),
                "radius_mm": float(self.radius_mm)}
