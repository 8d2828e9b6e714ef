"""The outline of a hole on the unrolled wall, found along rays from its centre.

A through hole has a sharp rim: the wall's brightness drops to the (near-black) hole
along a step blurred by the optics and the blending. The rim is where that step is
steepest, which does not depend on how bright the wall next to it is. A threshold at
a fixed fraction of the depth does: on a busy wall (corrosion, stains) the wall beside
the rim is darker or brighter than the neighbourhood's median, and the threshold
crossing moves off the rim by a sizeable part of the blur width, all round the hole.

So the rim is located on each of K rays from the hole's centre (in millimetres on the
wall, whatever the mosaic's two pixel pitches) at the maximum of the smoothed radial
derivative, to a fraction of a pixel. A dark pit or stain touching the rim moves that
maximum outward on the rays that cross it; an ellipse fitted to the rim points
(OpenCV) with those rays left out (a robust residual gate from the points' own spread)
gives the rim there instead. The area is the polygon's (shoelace), the centre its
centroid. Neither scikit-image nor OpenCV locates a step along given rays, hence this
module.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from pipestitch.imaging import mad_sigma

__all__ = ["RimOutline", "rim_outline"]

STEP_PX = 0.25            # sampling step along each ray
SMOOTH_PX = 1.0           # derivative smoothing (about one pixel of blur)
GATE_SIGMAS = 3.0


@dataclass(frozen=True)
class RimOutline:
    """A rim in mosaic pixels: ``rows``/``cols`` of its points (one per ray), the
    polygon's area (mm^2) and centroid, the fraction of rays replaced by the ellipse,
    and the image's blur across the rim (Gaussian sigma, pixels)."""

    rows: np.ndarray
    cols: np.ndarray
    area_mm2: float
    centre_row: float
    centre_col: float
    outlier_fraction: float
    blur_px: float


def rim_outline(values: np.ndarray, centre_rc: tuple[float, float], radius_mm: float,
                pitch_mm: tuple[float, float], darker_inside: bool = True) -> RimOutline | None:
    """The rim of a hole around ``centre_rc`` (row, col) in ``values`` (finite array).

    Parameters
    ----------
    values : numpy.ndarray
        Image around the hole (any scale; NaN not allowed).
    centre_rc : tuple of float
        A point inside the hole (row, col).
    radius_mm : float
        A first guess of its radius; the rim is searched from 0.4 to 1.7 times it
        (plus two pixels).
    pitch_mm : tuple of float
        Millimetres per row and per column on the wall.
    darker_inside : bool
        True for a dark hole (the rim is a rise outward).

    Returns
    -------
    RimOutline or None
        None when fewer than half the rays show a rim inside the image.
    """
    pr, pc = pitch_mm
    pix = min(pr, pc)
    n_rays = int(np.clip(np.ceil(2 * np.pi * radius_mm / pix), 32, 720))
    phi = np.arange(n_rays) * (2 * np.pi / n_rays)
    r_mm = np.arange(0.0, 1.7 * radius_mm + 2 * pix, STEP_PX * pix)
    rows = centre_rc[0] + np.outer(np.sin(phi), r_mm) / pr
    cols = centre_rc[1] + np.outer(np.cos(phi), r_mm) / pc
    inside = ((rows >= 0) & (rows <= values.shape[0] - 1)
              & (cols >= 0) & (cols <= values.shape[1] - 1)).all(axis=1)
    if inside.sum() < n_rays / 2:
        return None
    profile = ndimage.map_coordinates(values.astype(np.float64), [rows, cols], order=1,
                                      mode="nearest")
    slope = ndimage.gaussian_filter1d(profile, SMOOTH_PX / STEP_PX, axis=1, order=1)
    slope *= 1.0 if darker_inside else -1.0
    window = r_mm >= 0.4 * radius_mm
    slope[:, ~window] = -np.inf
    peak, width2 = _subpixel_peak(slope)
    radius = peak * STEP_PX * pix
    radius[~inside] = np.nan
    # The steepest point of a blurred circular step lies sigma^2 / (2 r) inside the rim
    # (sigma: the image's blur, i.e. the peak's width less the smoothing added here).
    widths = width2[inside & np.isfinite(width2)]
    blur2 = max(float(np.median(widths)) - SMOOTH_PX**2, 0.0) * pix**2 if widths.size else 0.0
    radius += blur2 / (2 * np.maximum(radius, pix))
    x, y = radius * np.cos(phi), radius * np.sin(phi)          # mm, col and row axes
    keep = _ellipse_inliers(x, y, 0.01 * pix)
    if keep.sum() < 5:
        return None
    radius = np.where(keep, radius, _ellipse_radius(x[keep], y[keep], phi))
    x, y = radius * np.cos(phi), radius * np.sin(phi)
    area, cx, cy = _polygon_area_centroid(x, y)
    return RimOutline(rows=centre_rc[0] + y / pr, cols=centre_rc[1] + x / pc,
                      area_mm2=area, centre_row=centre_rc[0] + cy / pr,
                      centre_col=centre_rc[1] + cx / pc,
                      outlier_fraction=float(1 - keep.mean()),
                      blur_px=float(np.sqrt(blur2) / pix))


def _subpixel_peak(slope: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of each row's maximum, refined by the parabola through it and its
    neighbours, and the squared width (in pixels) of the Gaussian whose logarithm
    passes through the same three samples (NaN where they do not make a peak)."""
    k = np.clip(np.argmax(slope, axis=1), 1, slope.shape[1] - 2)
    i = np.arange(len(k))
    a, b, c = slope[i, k - 1], slope[i, k], slope[i, k + 1]
    denom = a - 2 * b + c
    ok = np.isfinite(denom) & (denom < 0)
    shift = np.where(ok, 0.5 * (a - c) / np.where(ok, denom, 1.0), 0.0)
    positive = ok & (a > 0) & (b > 0) & (c > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_curv = np.log(np.where(positive, a * c, 1.0)) - 2 * np.log(np.where(positive, b, 1.0))
        width2 = np.where(positive & (log_curv < 0), -(STEP_PX**2) / log_curv, np.nan)
    return k + np.clip(shift, -0.5, 0.5), width2


def _ellipse_inliers(x: np.ndarray, y: np.ndarray, floor_mm: float) -> np.ndarray:
    """Rays whose rim point lies on the ellipse fitted to the others.

    The first gate is on the radius itself (its median and robust spread: an
    ellipse's own variation stays well inside ``GATE_SIGMAS``); then an ellipse is
    fitted to the points kept and the gate applied to the radial residuals, until the
    set of points kept no longer changes.
    """
    radius = np.hypot(x, y)
    finite = np.isfinite(radius)
    if finite.sum() < 5:
        return finite
    keep = finite & _gate(radius - np.median(radius[finite]), finite, floor_mm)
    for _ in range(4):
        if keep.sum() < 5:
            return keep
        resid = radius - _ellipse_radius(x[keep], y[keep], np.arctan2(y, x))
        new = finite & _gate(resid, keep, floor_mm)
        if np.array_equal(new, keep):
            break
        keep = new
    return keep


def _gate(resid: np.ndarray, ref: np.ndarray, floor_mm: float) -> np.ndarray:
    """Residuals within ``GATE_SIGMAS`` robust sigmas (MAD of those in ``ref``, at least
    ``floor_mm``) of their median."""
    centre = float(np.median(resid[ref]))
    return np.abs(resid - centre) <= GATE_SIGMAS * max(mad_sigma(resid[ref]), floor_mm)


def _ellipse_radius(x: np.ndarray, y: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Distance from the origin to the ellipse fitted to (x, y) along directions phi."""
    pts = np.stack([x, y], axis=1).astype(np.float32)
    (ex, ey), (w, h), angle = cv2.fitEllipseDirect(pts)
    a, b, t = w / 2, h / 2, np.deg2rad(angle)
    # Ray p(s) = s u from the origin; in the ellipse frame q = R^T (s u - e).
    ux, uy = np.cos(phi), np.sin(phi)
    c, s = np.cos(t), np.sin(t)
    du, dv = c * ux + s * uy, -s * ux + c * uy
    eu, ev = c * ex + s * ey, -s * ex + c * ey
    qa = (du / a) ** 2 + (dv / b) ** 2
    qb = -2 * (du * eu / a**2 + dv * ev / b**2)
    qc = (eu / a) ** 2 + (ev / b) ** 2 - 1
    disc = np.maximum(qb * qb - 4 * qa * qc, 0.0)
    return (-qb + np.sqrt(disc)) / (2 * qa)


def _polygon_area_centroid(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Area and centroid of the closed polygon through (x, y) (shoelace)."""
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * float(cross.sum())
    if abs(area) < 1e-12:
        return 0.0, float(np.mean(x)), float(np.mean(y))
    cx = float(((x + xn) * cross).sum()) / (6 * area)
    cy = float(((y + yn) * cross).sum()) / (6 * area)
    return abs(area), cx, cy
