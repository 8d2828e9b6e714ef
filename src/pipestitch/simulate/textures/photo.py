"""A grey photo, mirror-tiled over the wall (see :func:`photo_texture`)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from pipestitch.camera.frames import to_grey
from pipestitch.geometry import WallGrid

__all__ = ["photo_texture"]


def _to_unit_grey(image: np.ndarray) -> np.ndarray:
    """A photo as grey float32 in [0, 1]: :func:`~pipestitch.camera.frames.to_grey`,
    clipped, after checking that it is a photo this texture takes.

    Accepted: 2-D, or 3-D with 3 (BGR) or 4 (BGRA) channels, at least 2 x 2 pixels;
    uint8, uint16 or float (finite; values outside [0, 1] are clipped).
    """
    img = np.asarray(image)
    colour = img.ndim == 3 and img.shape[2] in (3, 4)
    if not (img.ndim == 2 or colour) or img.shape[0] < 2 or img.shape[1] < 2:
        raise ValueError(f"photo: expected a 2-D grey image of at least 2x2, got {img.shape}")
    if img.dtype not in (np.uint8, np.uint16) and not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"photo: unsupported dtype {img.dtype}")
    if img.dtype.kind == "f" and not np.all(np.isfinite(img)):
        raise ValueError("photo: contains NaN or inf")
    return np.clip(to_grey(img), 0.0, 1.0)


def photo_texture(grid: WallGrid, image: np.ndarray, tile_mm: float) -> np.ndarray:
    """Tile a grey photo over the wall, mirrored so the tiling has no seams.

    The photo's width spans ``tile_mm`` along z; its height keeps the photo's
    aspect ratio, adjusted (by at most a factor 4/3, usually a few %) so that an
    even number of tiles fits around the circumference: with mirror tiling the
    pattern then closes seamlessly in theta. The photo's rows run around the pipe,
    its columns along z. Resampling: area-averaged with :func:`cv2.resize` to the
    grid's scale, then bicubic with wrap-around (:func:`cv2.warpAffine`) for the
    exact placement. Tile (0, 0) starts at theta = 0 and z = ``grid.z0_mm``.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    image : numpy.ndarray
        Grey photo, uint8 (0-255), uint16 or float (0-1); BGR(A) is converted to grey.
    tile_mm : float
        Width of one (unmirrored) copy of the photo on the wall, along z (mm).

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo in [0, 1].
    """
    if not (math.isfinite(tile_mm) and tile_mm > 0):
        raise ValueError(f"tile_mm: expected a positive number, got {tile_mm!r}")
    img = _to_unit_grey(image)
    h, w = img.shape
    tile_h_mm = tile_mm * h / w
    n_pairs = max(1, round(grid.circumference_mm / (2.0 * tile_h_mm)))
    tile_h_mm = grid.circumference_mm / (2 * n_pairs)
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    # Area prefilter when the photo has more than ~1.5 samples per grid pixel.
    th = min(h, max(2, round(1.5 * tile_h_mm / ws)))
    tw = min(w, max(2, round(1.5 * tile_mm / wz)))
    if (th, tw) != (h, w):
        img = cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA)
    h, w = img.shape
    top = np.concatenate([img, img[:, ::-1]], axis=1)
    period = np.ascontiguousarray(np.concatenate([top, top[::-1]], axis=0))
    # Photo pixel centres at ((k + 0.5) * tile / h) mm: src = pos * h / tile - 0.5.
    mz = wz * w / tile_mm
    ms = ws * h / tile_h_mm
    m = np.array([[mz, 0.0, -0.5], [0.0, ms, -0.5]])
    n_rows, n_cols = grid.shape
    out = cv2.warpAffine(period, m, (n_cols, n_rows), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_WRAP)
    np.clip(out, 0.0, 1.0, out=out)
    return out
