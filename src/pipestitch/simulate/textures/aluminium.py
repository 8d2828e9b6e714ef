"""Brushed aluminium: bright, feature-poor, fine streaks along the axis (see
:func:`aluminium_texture`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from pipestitch.geometry import WallGrid
from pipestitch.simulate.textures._texture_common import (
    as_rng,
    filtered_noise,
    lattice_shape,
    lattice_to_grid,
)

__all__ = ["aluminium_texture"]


def aluminium_texture(grid: WallGrid, rng: np.random.Generator | int) -> np.ndarray:
    """Brushed aluminium: bright, low contrast, fine streaks along the axis.

    Albedo 0.70 with a standard deviation of about 0.018 (2.5 %): fine streaks
    (0.05-1 mm across, ~6 mm correlation length along z), faint isotropic grain
    (>= 0.5 mm), slow mottling (~15 mm) and a few faint near-axial scratches (about
    one per 15 cm^2, 5-40 mm long, +-2 %). Deliberately feature-poor: registration
    has little to lock on to, especially along z.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source (the noise field, then the scratches).

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo in [0, 1] (essentially 0.63-0.77).
    """
    rng = as_rng(rng)
    circ, length = grid.circumference_mm, grid.length_mm
    shape = lattice_shape(grid, 0.04, 0.25)
    dx = (circ / shape[0], length / shape[1])
    fs_hi = 0.35 / dx[0]
    fz_hi = 0.35 / dx[1]
    l_z = 6.0

    def brushed(fs: np.ndarray, fz: np.ndarray) -> np.ndarray:
        cut = np.exp(-(fs / fs_hi) ** 2 - (fz / fz_hi) ** 2)
        streak = (fs * fs + 0.5**2) ** -0.25 * np.exp(-0.5 * (fz * l_z) ** 2)
        f2 = fs * fs + fz * fz
        grain = np.exp(-f2 / 1.0**2)
        mottle = np.exp(-f2 * 15.0**2)
        streak /= math.sqrt(float(np.mean(streak * streak * cut * cut)))
        grain /= math.sqrt(float(np.mean(grain * grain * cut * cut)))
        mottle /= math.sqrt(float(np.mean(mottle * mottle)))
        return (1.0 * streak + 0.35 * grain + 0.6 * mottle) * cut

    alb = filtered_noise(rng, shape, dx, brushed)
    alb *= np.float32(0.018)
    alb += np.float32(0.70)
    # A few faint scratches, drawn on the lattice (half-widths ~1 lattice node).
    n_scr = int(rng.poisson(circ * length / 1500.0))
    if n_scr:
        s0 = rng.uniform(0.0, circ, n_scr)
        z0 = rng.uniform(0.0, length, n_scr)
        ln = rng.uniform(5.0, 40.0, n_scr)
        tilt = np.deg2rad(rng.normal(0.0, 1.0, n_scr))
        sign = np.where(rng.random(n_scr) < 0.5, -1.0, 1.0)
        strength = rng.uniform(0.008, 0.02, n_scr)
        for polarity in (-1.0, 1.0):
            mask = np.zeros(shape, np.uint8)
            sel = sign == polarity
            for k in np.flatnonzero(sel):
                p0 = (z0[k] / dx[1], s0[k] / dx[0])
                p1 = ((z0[k] + ln[k] * math.cos(tilt[k])) / dx[1],
                      (s0[k] + ln[k] * math.sin(tilt[k])) / dx[0])
                val = round(255 * strength[k] / 0.02)
                for dy in (0.0, shape[0], -shape[0]):
                    cv2.line(mask, (round(p0[0] * 16), round((p0[1] + dy) * 16)),
                             (round(p1[0] * 16), round((p1[1] + dy) * 16)), val, 1,
                             cv2.LINE_AA, 4)
            alb += np.float32(0.02 * polarity / 255.0) * mask
    out = lattice_to_grid(alb, grid)
    del alb
    np.clip(out, 0.0, 1.0, out=out)
    return out
