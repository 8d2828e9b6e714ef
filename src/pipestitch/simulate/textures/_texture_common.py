"""What the textures share: the random source, the width of an antialiasing
ramp, and the periodic noise lattice.

Noise textures are drawn as white noise on a lattice whose spacing is set in
millimetres (about the grid pitch at the finest), shaped by a filter in the Fourier
domain (so they are periodic in theta by construction), composed at lattice
resolution and brought to the grid with one bicubic warp that wraps in theta.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
import scipy.fft as sfft

from pipestitch.geometry import WallGrid

__all__ = ["WARP_CHUNK", "as_rng", "filtered_noise", "lattice_shape", "lattice_to_grid",
           "ramp_width", "scale_wrapped"]


def as_rng(rng: np.random.Generator | int) -> np.random.Generator:
    """The generator itself, or a new one seeded with the int."""
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, int | np.integer):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng: expected a numpy Generator or an int seed, got {type(rng).__name__}")


def ramp_width(ds: np.ndarray, dz: np.ndarray, dist: np.ndarray, ws: float,
               wz: float) -> np.ndarray:
    """Pixel extent across an edge with normal (ds, dz)/dist, for analytic antialiasing.

    The ramp width whose variance matches that of the pixel footprint projected on
    the normal: ``sqrt((n_s ws)^2 + (n_z wz)^2)``; exactly the pixel pitch for
    square pixels.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.sqrt((ds * ws) ** 2 + (dz * wz) ** 2) / dist
    return np.where(dist > 0, w, math.sqrt(0.5 * (ws * ws + wz * wz)))


def lattice_shape(grid: WallGrid, cell_s_mm: float, cell_z_mm: float) -> tuple[int, int]:
    """Noise lattice size: spacing ~ the given cells (never much finer than the grid)."""
    cs = max(cell_s_mm, grid.mm_per_px_circ)
    cz = max(cell_z_mm, grid.mm_per_px_axial)
    # FFT-friendly sizes, at most a few % above the grid's own where cs, cz are its pitch.
    n_s = sfft.next_fast_len(max(8, math.ceil(grid.circumference_mm / cs - 1e-6)), real=True)
    n_z = sfft.next_fast_len(max(8, math.ceil(grid.length_mm / cz - 1e-6)), real=True)
    return n_s, n_z


def filtered_noise(rng: np.random.Generator, shape: tuple[int, int],
                    spacing_mm: tuple[float, float],
                    amplitude: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Periodic Gaussian noise with a given amplitude spectrum, zero mean, unit std.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the white noise.
    shape : (int, int)
        Lattice size (theta, z); the noise is periodic over it in both directions.
    spacing_mm : (float, float)
        Lattice spacing (mm) along theta (arc) and z.
    amplitude : callable
        ``amplitude(f_s, f_z)`` -> filter gain at spatial frequencies in cycles/mm
        (broadcast arrays, float32).
    """
    # One thread (scipy's default), not ``workers=-1``: a multi-threaded transform starts
    # pocketfft's thread pool, which stops and restarts its threads around every fork
    # (pthread_atfork); the simulator forks its renderers after building the wall, and
    # that stop could wait forever (seen: `pipestitch simulate --workers 2` hung in the
    # fork). Same values either way (each 1-D transform is the same on any thread).
    white = rng.standard_normal(shape, dtype=np.float32)
    spec = sfft.rfft2(white)
    del white
    f_s = sfft.fftfreq(shape[0], d=spacing_mm[0]).astype(np.float32)[:, None]
    f_z = sfft.rfftfreq(shape[1], d=spacing_mm[1]).astype(np.float32)[None, :]
    gain = np.asarray(amplitude(f_s, f_z), dtype=np.float32)
    gain[0, 0] = 0.0
    spec *= gain
    del gain
    out = sfft.irfft2(spec, s=shape).astype(np.float32, copy=False)
    del spec
    std = float(out.std())
    out -= np.float32(out.mean())
    if std > 0:
        out *= np.float32(1.0 / std)
    return out


def lattice_to_grid(lat: np.ndarray, grid: WallGrid) -> np.ndarray:
    """Resample a periodic lattice covering the whole wall onto the grid (bicubic, wrapped).

    Lattice node (k, l) sits at theta = k * 360 / n_k and z = z0 + l * length / n_l;
    the lattice is periodic in both directions, so the warp wraps (seamless in theta).
    """
    n_rows, n_cols = grid.shape
    if lat.shape == (n_rows, n_cols):
        return np.ascontiguousarray(lat, dtype=np.float32)
    return scale_wrapped(lat, n_rows, n_cols)


WARP_CHUNK = 8192     # output columns per cv2.warpAffine call (it fails on very wide images)


def scale_wrapped(src: np.ndarray, n_rows: int, n_cols: int, *,
                  chunk_cols: int = WARP_CHUNK) -> np.ndarray:
    """Bicubic rescale of a periodic image (both axes wrap) to n_rows x n_cols.

    Output node (i, j) samples the source at (i·rows/n_rows, j·cols/n_cols). Done in
    chunks of output columns, each from a wrapped crop of the source with a margin, so
    that OpenCV's remap-based warp never sees a source or output wider than it handles
    (a 20 m wall at full resolution crashed it).

    Parameters
    ----------
    src : numpy.ndarray, shape (rows, cols) or (rows, cols, channels)
        The periodic image.
    n_rows, n_cols : int
        Output size.
    chunk_cols : int
        At most this many output (and source) columns per warp.

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols, ...), float32
    """
    sy, sx = src.shape[0] / n_rows, src.shape[1] / n_cols
    pad = 4
    rows = np.arange(-pad, src.shape[0] + pad) % src.shape[0]
    chunk = max(1, min(chunk_cols, int(chunk_cols / max(sx, 1.0))))
    out = np.empty((n_rows, n_cols) + src.shape[2:], np.float32)
    for c0 in range(0, n_cols, chunk):
        c1 = min(n_cols, c0 + chunk)
        s0 = int(np.floor(c0 * sx)) - pad
        s1 = int(np.ceil((c1 - 1) * sx)) + pad + 1
        piece = src[rows][:, np.arange(s0, s1) % src.shape[1]]
        m = np.array([[sx, 0.0, c0 * sx - s0], [0.0, sy, float(pad)]])
        out[:, c0:c1] = cv2.warpAffine(piece, m, (c1 - c0, n_rows),
                                       flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                                       borderMode=cv2.BORDER_REPLICATE).reshape(
            (n_rows, c1 - c0) + src.shape[2:])
    return out
