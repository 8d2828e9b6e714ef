"""A second ring in a laser frame: the candidates a ring fit left over.

A shiny wall can mirror the laser line into a second closed curve (a ghost of the
ring at another image radius), and one as strong as the ring can win the fit: the
pose and the pipe's radius are then those of the ghost. The ring fit keeps one
candidate per ray; what it left is looked at again here, with the ridge maxima too
faint for the ring search's relative floor when the detection carries them (a glow
much brighter than the ring, a laser-lit mirror mount, sets that floor above much of
the ring itself): the same floor is then taken relative to the leftovers' own
strength. Where the leftovers still
make a ring over much of the frame, the caller fits them too and chooses between the
two curves with what it knows of the pipe (:func:`pipestitch.pipeline.posing.fit_frame`:
the one nearer the nominal radius).

Pure and vectorised: the detection's candidates and the fitted ring's image points in,
the leftover candidates out.
"""

from __future__ import annotations

import math

import numpy as np

from pipestitch.pose.ring import RingDetection

__all__ = ["LINE_GATE_SIGMAS", "leftover_ring"]

# A candidate further than this many line sigmas (measured on the frame) from the
# fitted ring along its ray is not that ring: the line's half width at 1 % of its peak
# is 3 sigma, and the fitted ring's image is interpolated between its kept points.
LINE_GATE_SIGMAS = 4.0


def leftover_ring(detection: RingDetection, ring_pixels: np.ndarray, centre: np.ndarray,
                  min_rays: int) -> RingDetection | None:
    """The candidates of ``detection`` off the fitted ring, when they lie on at least
    ``min_rays`` rays (else None: no second ring is possible).

    Parameters
    ----------
    detection : RingDetection
        The frame's ring candidates (:func:`pipestitch.pose.ring.detect_ring`).
    ring_pixels : numpy.ndarray, shape (M, 2)
        Image points (col, row) of the fitted ring (its kept inliers).
    centre : numpy.ndarray, shape (2,)
        The image of the optical axis, about which the detection's rays run.
    min_rays : int
        Fewest rays the leftovers must reach.

    Returns
    -------
    RingDetection or None
        The leftover candidates, ranked again within their rays (same order as the
        detection's: by ray, strongest first), above ``detection.relative_floor`` times
        their typical strength.
    """
    n_az = detection.n_azimuths
    if len(ring_pixels) < 3:
        return None
    detection = _with_fainter(detection)
    # cheap test first: a second ring needs a second candidate on min_rays rays at least
    if np.count_nonzero(detection.rank >= 1) < min_rays // 2:
        return None
    ring_offset = np.asarray(ring_pixels, float) - centre
    ring_angle = np.mod(np.arctan2(ring_offset[:, 1], ring_offset[:, 0]), 2 * np.pi)
    ring_radius = np.hypot(ring_offset[:, 0], ring_offset[:, 1])
    order = np.argsort(ring_angle)
    angle = detection.azimuth * (2 * np.pi / n_az)
    expected = np.interp(angle, ring_angle[order], ring_radius[order], period=2 * np.pi)
    offset = detection.pixels - centre
    radius = np.hypot(offset[:, 0], offset[:, 1])
    sigma = detection.line_sigma_px if math.isfinite(detection.line_sigma_px) else 1.0
    off = np.abs(radius - expected) > LINE_GATE_SIGMAS * sigma
    off &= detection.snr > detection.relative_floor * _typical_snr(detection.azimuth[off],
                                                                   detection.snr[off])
    azimuth = detection.azimuth[off]
    if len(np.unique(azimuth)) < min_rays:
        return None
    return RingDetection(pixels=detection.pixels[off], azimuth=azimuth,
                         rank=_ranks_within_rays(azimuth, detection.rank[off]),
                         snr=detection.snr[off], n_azimuths=n_az, noise=detection.noise,
                         line_sigma_px=detection.line_sigma_px,
                         led_shift_px=detection.led_shift_px)


def _with_fainter(detection: RingDetection) -> RingDetection:
    """The detection's candidates and its ``fainter`` maxima as one, grouped by ray."""
    faint = detection.fainter
    if faint is None or not faint.azimuth.size:
        return detection
    azimuth = np.concatenate([detection.azimuth, faint.azimuth])
    rank = np.concatenate([detection.rank, faint.rank])
    order = np.lexsort((rank, azimuth))
    return RingDetection(pixels=np.concatenate([detection.pixels, faint.pixels])[order],
                         azimuth=azimuth[order], rank=rank[order],
                         snr=np.concatenate([detection.snr, faint.snr])[order],
                         n_azimuths=detection.n_azimuths, noise=detection.noise,
                         line_sigma_px=detection.line_sigma_px,
                         relative_floor=detection.relative_floor,
                         led_shift_px=detection.led_shift_px)


def _typical_snr(azimuth: np.ndarray, snr: np.ndarray) -> float:
    """The median over the rays of each ray's strongest ``snr`` (0 for none): what
    :func:`pipestitch.pose.ring.detect_ring` takes a frame's typical ring response as."""
    if not azimuth.size:
        return 0.0
    strongest = np.full(int(azimuth.max()) + 1, -np.inf)
    np.maximum.at(strongest, azimuth, snr)
    return float(np.median(strongest[np.isfinite(strongest)]))


def _ranks_within_rays(azimuth: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """0, 1, ... within each ray, in the order of ``rank`` (candidates grouped by ray)."""
    order = np.lexsort((rank, azimuth))
    ray = azimuth[order]
    starts = np.flatnonzero(np.r_[True, ray[1:] != ray[:-1]])
    first = np.repeat(starts, np.diff(np.r_[starts, len(ray)]))
    out = np.empty_like(rank)
    out[order] = np.arange(len(ray)) - first
    return out
