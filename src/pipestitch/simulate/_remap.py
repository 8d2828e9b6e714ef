"""Bilinear, wrapping sampling of a wall texture with ``cv2.remap``, at any width.

OpenCV's remap takes sources and maps of fewer than 32767 columns; a long run's
wall texture has more. :func:`remap_wrap` hands OpenCV the columns the maps reach in
crops it accepts, :func:`remap_points` samples scattered points. The renderer
(:mod:`pipestitch.simulate.render`) samples its textures through these.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["REMAP_MAX", "remap_points", "remap_wrap"]

REMAP_MAX = 32766   # cv2.remap: source and maps below SHRT_MAX columns and rows


def remap_wrap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """``cv2.remap`` (bilinear, wrapping) that also takes textures wider than it allows.

    A long run's wall texture passes 32767 columns: the columns the maps reach are then
    handed to OpenCV in crops of fewer columns (with a margin for the interpolation),
    each sampling the map entries that fall in it. A frame sees the wall from behind
    the camera to far down the pipe, so one frame may need several crops.

    Parameters
    ----------
    image : numpy.ndarray, shape (rows, cols)
        The texture (both axes wrap).
    map_x, map_y : numpy.ndarray, float32
        Column and row of each sample (``cv2.remap``'s maps); NaN samples give 0.

    Returns
    -------
    numpy.ndarray
        The samples, of the maps' shape and the image's dtype.
    """
    if image.shape[1] <= REMAP_MAX:
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    map_x = np.mod(map_x, image.shape[1])   # BORDER_WRAP's columns, before cropping
    finite = np.isfinite(map_x)
    lo = int(np.floor(map_x[finite].min())) if finite.any() else 0
    chunk = REMAP_MAX - 8
    part = np.where(finite, np.floor((map_x - lo) / chunk), -1).astype(np.int64)
    out = np.zeros(map_x.shape, image.dtype)
    for k in np.unique(part[part >= 0]):
        mask = part == k
        # Only the columns this part reaches (a frame sees a few thousand): copying
        # whole 32k-column crops of a 20 m texture for every frame took seconds.
        reach = map_x[mask]
        c0 = max(int(np.floor(reach.min())) - 2, 0)
        c1 = min(int(np.ceil(reach.max())) + 4, image.shape[1])
        crop = np.ascontiguousarray(image[:, c0:c1])
        sample = cv2.remap(crop, (map_x - c0).astype(np.float32), map_y, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_WRAP)
        out[mask] = sample[mask]
    return out


def remap_points(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at scattered points (rows wrap around).

    cv2.remap wants 2-D maps of fewer than 32767 columns, so the points are laid out
    in rows of 1024.

    Parameters
    ----------
    image : numpy.ndarray, shape (rows, cols)
        The texture (both axes wrap).
    x, y : numpy.ndarray
        Column and row of each point.

    Returns
    -------
    numpy.ndarray, shape (N,)
        The samples, in the points' order.
    """
    n = x.size
    width = 1024
    rows = max(1, -(-n // width))
    # padding repeats the first point, so it does not widen the columns reached
    mx = np.full(rows * width, x.flat[0] if n else 0.0, np.float32)
    my = np.full(rows * width, y.flat[0] if n else 0.0, np.float32)
    mx[:n], my[:n] = x, y
    out = remap_wrap(image, mx.reshape(rows, width), my.reshape(rows, width))
    return out.ravel()[:n]
