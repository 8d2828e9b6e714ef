"""Rust / corrosion: fractal noise, stains, bright flakes and pits (see
:func:`corrosion_texture`).
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
    scale_wrapped,
)

__all__ = ["corrosion_texture"]

_ROW_CHUNK = 1024           # rows per chunk for full-size element-wise passes


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 + 0.5 * np.tanh(0.5 * x)).astype(np.float32, copy=False)


def _multiply_lut(out: np.ndarray, mask: np.ndarray, lut: np.ndarray) -> None:
    """``out *= lut[mask]`` in row chunks (no full-size temporary)."""
    lut = np.ascontiguousarray(lut, dtype=np.float32).reshape(1, 256)
    for r0 in range(0, out.shape[0], _ROW_CHUNK):
        r1 = min(out.shape[0], r0 + _ROW_CHUNK)
        out[r0:r1] *= cv2.LUT(mask[r0:r1], lut)


def _draw_ellipses_wrapped(mask: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                           ax_rows: np.ndarray, ax_cols: np.ndarray, values: np.ndarray,
                           angle_deg: np.ndarray | None = None) -> None:
    """Filled antialiased ellipses on a uint8 image, repeated across the theta wrap.

    Positions and half-axes are in (fractional) pixels; ``values`` 0..255.
    """
    n_rows = mask.shape[0]
    shift = 4
    scale = 1 << shift
    ang = np.zeros(len(rows)) if angle_deg is None else angle_deg
    reach = np.maximum(ax_rows, ax_cols) + 2
    for dy in (0, n_rows, -n_rows):
        sel = slice(None) if dy == 0 else (rows + dy + reach >= 0) & (rows + dy - reach < n_rows)
        if dy != 0 and not np.any(sel):
            continue
        cx = np.rint(cols[sel] * scale).astype(np.int64).tolist()
        cy = np.rint((rows[sel] + dy) * scale).astype(np.int64).tolist()
        ax = np.maximum(1, np.rint(ax_cols[sel] * scale)).astype(np.int64).tolist()
        ay = np.maximum(1, np.rint(ax_rows[sel] * scale)).astype(np.int64).tolist()
        vv = np.asarray(values[sel]).astype(np.int64).tolist()
        aa = np.asarray(ang[sel], dtype=np.float64).tolist()
        for x, y, a, b, v, t in zip(cx, cy, ax, ay, vv, aa, strict=True):
            cv2.ellipse(mask, (x, y), (a, b), t, 0, 360, int(v), -1, cv2.LINE_AA, shift)


def corrosion_texture(grid: WallGrid, rng: np.random.Generator | int) -> np.ndarray:
    """Rust / corrosion: fractal noise, stains, bright flakes and pits.

    Built from (all sizes on the wall, mm):

    * fractal (1/f amplitude) noise from ~0.2 mm to ~20 mm, mapped to a lognormal
      albedo (median 0.33, about +-26 %);
    * large stains (1/f^1.5 noise, 2-15 mm blobs) darkening by up to 50 %, and a few
      brighter flakes (bare metal / scale, +0.2) where that field is lowest;
    * pits, ~0.08 per mm^2 and denser in the stains: lognormal diameters
      (median 0.35 mm, 0.08-2 mm), a dark core (x0.28 to x0.5) with a lighter halo.

    The noise is periodic in theta (and along the grid's z extent); pits are drawn
    across the wrap, so the texture is seamless.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source (the noise fields, then the pits).

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo in [0, 1] (mostly 0.1-0.6).
    """
    rng = as_rng(rng)
    circ, length = grid.circumference_mm, grid.length_mm
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    # Fine fractal field.
    shape = lattice_shape(grid, 0.08, 0.08)
    dx = (circ / shape[0], length / shape[1])
    f_hi = 0.35 / max(dx)

    def fractal(fs: np.ndarray, fz: np.ndarray) -> np.ndarray:
        f2 = fs * fs + fz * fz
        gain = np.log(f2 + np.float32(1 / 20.0**2))     # exp/log, not pow: SIMD in numpy
        gain *= np.float32(-0.45)
        f2 *= np.float32(-1.0 / (f_hi * f_hi))
        gain += f2
        return np.exp(gain, out=gain)

    field = filtered_noise(rng, shape, dx, fractal)
    # Coarse stain field, brought to the fine lattice.
    cshape = (max(8, min(shape[0], math.ceil(circ / 0.5))),
              max(8, min(shape[1], math.ceil(length / 0.5))))
    cdx = (circ / cshape[0], length / cshape[1])

    def blotch(fs: np.ndarray, fz: np.ndarray) -> np.ndarray:
        f2 = fs * fs + fz * fz
        return (f2 + (1 / 15.0) ** 2) ** -0.75 * np.exp(-f2 / 0.5**2)

    stain_c = filtered_noise(rng, cshape, cdx, blotch)
    # Stains darken (x0.5 at most), flakes brighten (+0.2): computed on the coarse
    # lattice, brought to the fine one as a 2-channel (multiplier, offset) image.
    mult_add = np.dstack([1.0 - 0.5 * _sigmoid((stain_c - 0.4) / 0.3),
                          0.2 * _sigmoid((-stain_c - 1.8) / 0.12)]).astype(np.float32)
    mult_add = scale_wrapped(mult_add, shape[0], shape[1])
    alb = field                      # lognormal: positive, darker regions compressed
    alb *= np.float32(0.26)
    np.exp(alb, out=alb)
    alb *= np.float32(0.33)
    alb *= mult_add[:, :, 0]
    alb += mult_add[:, :, 1]
    del mult_add
    out = lattice_to_grid(alb, grid)
    del alb
    # Pits at full resolution.
    n_rows, n_cols = grid.shape
    area = circ * length
    n_cand = int(rng.poisson(0.08 * area / 0.55))
    s_c = rng.uniform(0.0, circ, n_cand)
    z_c = rng.uniform(-0.5 * wz, length - 0.5 * wz, n_cand)
    ks = np.minimum((s_c / cdx[0]).astype(np.int64), cshape[0] - 1)
    kz = np.clip(((z_c + 0.5 * wz) / cdx[1]).astype(np.int64), 0, cshape[1] - 1)
    keep = rng.random(n_cand) < 0.25 + 0.75 * _sigmoid(2.0 * stain_c[ks, kz])
    diam = np.clip(np.exp(rng.normal(math.log(0.35), 0.5, n_cand)), 0.08, 2.0)
    core = rng.uniform(0.5, 1.0, n_cand) * 255.0
    aspect = rng.uniform(0.8, 1.25, n_cand)
    angle = rng.uniform(0.0, 180.0, n_cand)
    s_c, z_c, diam, core, aspect, angle = (x[keep] for x in (s_c, z_c, diam, core, aspect,
                                                             angle))
    rows, cols = s_c / ws, z_c / wz
    r_s = 0.5 * diam * aspect / ws
    r_z = 0.5 * diam / aspect / wz
    mask = np.zeros((n_rows, n_cols), np.uint8)
    _draw_ellipses_wrapped(mask, rows, cols, 1.7 * r_s, 1.7 * r_z, np.full(len(rows), 70.0),
                           angle)
    _draw_ellipses_wrapped(mask, rows, cols, r_s, r_z, core, angle)
    _multiply_lut(out, mask, 1.0 - 0.72 * np.arange(256) / 255.0)
    np.clip(out, 0.0, 1.0, out=out)
    return out
