"""Laser frame -> sub-pixel laser-ring points with a confidence.

The ring surrounds the optical axis, so every ray from the image of the optical
axis crosses it once. The frame is resampled on a polar grid about that point
(``cv2.remap``), each radial profile is matched against a ridge (a
difference-of-Gaussians tuned to a thin line, which answers weakly to broad glints
and steps), the strongest ridges above the frame's own noise level are kept as
candidates, and each is located to sub-pixel precision by the centroid of its
background-subtracted profile. Candidates are ranked per azimuth; outliers
(glints, reflections) are removed later by the geometric fit, which knows that
the ring lies on the laser plane (see :mod:`pipestitch.pose.fit`).

What this module does not do: decide which candidate lies on the ring when two
are equally strong (it returns both, ranked) or know the pose.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from pipestitch._runtime import scratch
from pipestitch.camera import CameraModel
from pipestitch.imaging import gaussian_blur, mad_sigma, median, scaled_float32
from pipestitch.pose._ring_kernels import (
    centroids,
    flatten_by_moved_reflectance,
    flatten_by_reflectance,
    line_widths,
    ridge_peaks,
)
from pipestitch.pose.pair_motion import MAX_SHIFT_RADII, LedShift, led_shift

__all__ = ["RingDetection", "detect_ring", "laser_channel", "polar_crop", "polar_grid",
           "prepare_laser_frame", "ring_band_px", "ring_centre"]


@dataclass(frozen=True)
class RingDetection:
    """Candidate ring points of one laser frame.

    Attributes
    ----------
    pixels : numpy.ndarray, shape (N, 2)
        Sub-pixel points (col, row).
    azimuth : numpy.ndarray, shape (N,)
        Index of the polar ray each point was found on.
    rank : numpy.ndarray, shape (N,)
        0 for the strongest candidate of its ray, 1 for the next, ...
    snr : numpy.ndarray, shape (N,)
        Ridge strength divided by the frame's noise level.
    n_azimuths : int
        Number of polar rays searched.
    noise : float
        Estimated noise of the ridge response (fraction of full scale).
    line_sigma_px : float
        Gaussian sigma of the laser line across the ring, measured on this frame (its
        full width at half maximum / 2.355, median over the strongest candidates); the
        width the ridge filter assumed when too few candidates were found to measure it.
    fainter : RingDetection or None
        The ridge maxima above the noise but under ``relative_floor`` times the frame's
        typical ring response, located as these (their ranks follow these on each
        ray): not ring candidates, but what a ring fainter than a reflection in the
        same frame leaves (:mod:`pipestitch.pose.second_ring`).
    relative_floor : float
        That fraction (:func:`detect_ring`'s ``min_relative``).
    led_shift_px : float
        How far out along the rays (px, mean over the ring) the LED frame's wall lay
        from the laser frame's, where the ring was searched with the reflectance read
        there (:mod:`pipestitch.pose.pair_motion`: the probe moved between the frames);
        0 where the LED frame's wall shows that the two were taken together, NaN where
        it cannot tell (no LED frame, too little texture under the line, no ring).
    """

    pixels: np.ndarray
    azimuth: np.ndarray
    rank: np.ndarray
    snr: np.ndarray
    n_azimuths: int
    noise: float
    line_sigma_px: float = float("nan")
    fainter: RingDetection | None = None
    relative_floor: float = 0.0
    led_shift_px: float = float("nan")

    @property
    def coverage(self) -> float:
        """Fraction of azimuths with at least one candidate."""
        if not self.n_azimuths or not self.azimuth.size:
            return 0.0
        return float(np.count_nonzero(np.bincount(self.azimuth)) / self.n_azimuths)

    def best(self) -> np.ndarray:
        """The strongest candidate of every ray, (M, 2)."""
        return self.pixels[self.rank == 0]


def laser_channel(img: np.ndarray) -> int | None:
    """Channel of a colour frame with the highest peak-over-median contrast (None if grey).

    A red laser lives in one channel; a grey conversion would dilute it with the
    other two.
    """
    arr = np.asarray(img)
    if arr.ndim != 3:
        return None
    step = max(1, arr.shape[0] // 256)
    sub = arr[::step, ::step, :3]
    if arr.dtype in (np.uint8, np.uint16):
        contrast = [_integer_contrast(sub[..., c]) for c in range(sub.shape[2])]
    else:
        flat = sub.reshape(-1, sub.shape[2]).astype(np.float32)
        contrast = np.percentile(flat, TOP_PERCENT, axis=0) - np.median(flat, axis=0)
    return int(np.argmax(contrast))


TOP_PERCENT = 99.9   # the laser's peak: a percentile, so that a few hot pixels do not count


def _integer_contrast(values: np.ndarray) -> np.float32:
    """``numpy.percentile(v, TOP_PERCENT) - numpy.median(v)`` of integer ``values`` as
    float32 (what :func:`laser_channel` compares), from their histogram: the two order
    statistics either side of each, combined as numpy combines them for a float32
    array (its linear method; tests/pose/test_ring.py holds it to numpy's). A
    frame's sample is ~78,000 pixels; numpy partitions them for each (4.7-4.9 ms for
    three channels), a histogram takes 0.5 ms."""
    cumulative = np.cumsum(np.bincount(values.ravel()))
    n = int(cumulative[-1])

    def ranked(rank: int) -> np.float32:   # the value at this rank of the sorted values
        return np.float32(np.searchsorted(cumulative, rank, side="right"))

    q = TOP_PERCENT / 100
    at = (n - 1) * q   # numpy's virtual index for its linear method (float64)
    if at >= n - 1:
        top = ranked(n - 1)
    else:   # float32 values weighted by float64 weights taken as float32
        low = math.floor(at)
        a, b, gamma = ranked(low), ranked(low + 1), at - low
        step = b - a
        top = (b - step * np.float32(1 - gamma) if gamma >= 0.5
               else a + step * np.float32(gamma))
    return top - (ranked((n - 1) // 2) + ranked(n // 2)) / np.float32(2)


def prepare_laser_frame(img: np.ndarray, channel: int | None = None, *,
                        out: np.ndarray | None = None) -> np.ndarray:
    """Grey float32 in [0, 1] that keeps the laser's contrast.

    8- and 16-bit frames are scaled by their dtype's range. Colour frames give
    ``channel``, by default the laser's (:func:`laser_channel`). ``out``: a float32
    array of the frame's size to write into (see :mod:`pipestitch._runtime.scratch`).
    """
    arr = np.asarray(img)
    if arr.dtype.kind not in "uif":
        raise ValueError(f"laser frame: expected a numeric image, got dtype {arr.dtype}")
    integer = arr.dtype.kind in "ui"
    scale = np.float32(1.0 / np.iinfo(arr.dtype).max if integer else 1.0)
    if arr.ndim == 3:
        index = laser_channel(arr) if channel is None else min(channel, arr.shape[2] - 1)
        arr = arr[..., index]
    elif arr.ndim != 2:
        raise ValueError(f"laser frame: expected a 2-D or 3-D image, got shape {arr.shape}")
    # Cast and scale in one pass (the float32 arithmetic of a cast, then a product).
    arr = scaled_float32(arr, scale, out=out)
    # Only a float frame can hold NaN or infinities.
    if not integer and not np.all(np.isfinite(arr)):
        arr = np.nan_to_num(arr, nan=0.0, posinf=0.0, neginf=0.0)
    return arr


@functools.lru_cache(maxsize=8)
def ring_centre(camera: CameraModel) -> np.ndarray:
    """The image of the optical axis (col, row), about which :func:`detect_ring`'s rays
    run (cached, read-only)."""
    centre = camera.project(np.array([[0.0, 0.0, 1.0]]))[0]
    centre.flags.writeable = False
    return centre


@functools.lru_cache(maxsize=8)
def polar_grid(camera: CameraModel, n_azimuths: int, step_px: float,
               band_px: tuple[float, float] | None = None,
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sampling maps of the rays :func:`detect_ring` searches: from the image of the
    optical axis out to the lens edge (or over the image radii ``band_px`` only).

    The same for every frame of a run: cached (read-only arrays).

    Parameters
    ----------
    camera : CameraModel
        Camera model.
    n_azimuths : int
        Number of rays, evenly spaced in azimuth from 0.
    step_px : float
        Spacing of the samples along a ray, px.
    band_px : (float, float), optional
        Image radii about the image of the optical axis to sample between.

    Returns
    -------
    map_x, map_y : numpy.ndarray, shape (n_azimuths, n_samples), float32
        Image column and row of each sample (``cv2.remap``'s maps).
    radii : numpy.ndarray, shape (n_samples,)
        Image radius of each sample column, px.
    centre : numpy.ndarray, shape (2,)
        The image of the optical axis (col, row).
    """
    centre = ring_centre(camera)
    edge_theta = min(camera.max_incidence_rad, np.deg2rad(100.0))
    phi = np.linspace(0, 2 * np.pi, n_azimuths, endpoint=False)
    edge_rays = np.stack([np.sin(edge_theta) * np.cos(phi), np.sin(edge_theta) * np.sin(phi),
                          np.full_like(phi, np.cos(edge_theta))], axis=1)
    edge = camera.project(edge_rays)
    r_max = float(np.nanmax(np.linalg.norm(edge - centre, axis=1)))
    r_lo, r_hi = (2.0, r_max) if band_px is None else (max(2.0, band_px[0]),
                                                        min(r_max, band_px[1]))
    radii = np.arange(r_lo, max(r_hi, r_lo + step_px), step_px)
    map_x = (centre[0] + np.cos(phi)[:, None] * radii[None, :]).astype(np.float32)
    map_y = (centre[1] + np.sin(phi)[:, None] * radii[None, :]).astype(np.float32)
    for arr in (map_x, map_y, radii, centre):
        arr.flags.writeable = False
    return map_x, map_y, radii, centre


# The crop reaches this far beyond the samples: bilinear reads the next pixel, and the
# LED frame's 0.5 px blur (a 5-tap kernel) must not see the crop's edge there.
CROP_PAD_PX = 4


@functools.lru_cache(maxsize=8)
def polar_crop(camera: CameraModel, n_azimuths: int, step_px: float,
               band_px: tuple[float, float] | None = None,
               ) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray]:
    """The part of the frame :func:`polar_grid`'s maps read, and the maps relative to it.

    Converting and blurring only that part gives the polar samples of the whole frame
    exactly: the maps move by whole pixels (exact in float32 below 2**24, and so are the
    interpolation weights), and every pixel read, and every pixel the blur of a pixel
    read reaches, is inside the part unless it is outside the frame, where the constant
    border applies as before. Cached (read-only arrays).

    Parameters
    ----------
    camera, n_azimuths, step_px, band_px
        As :func:`polar_grid`.

    Returns
    -------
    part : (slice, slice)
        The (rows, cols) of the frame read; the whole frame when the rays miss it.
    map_x, map_y : numpy.ndarray, float32
        :func:`polar_grid`'s maps, relative to the part's first column and row.
    """
    map_x, map_y, _, _ = polar_grid(camera, n_azimuths, step_px, band_px)

    def span(m: np.ndarray, size: int) -> tuple[int, int]:
        lo, hi = float(np.nanmin(m)), float(np.nanmax(m))
        return (max(0, min(size, int(np.floor(lo)) - CROP_PAD_PX)),
                max(0, min(size, int(np.ceil(hi)) + CROP_PAD_PX + 1)))

    (x0, x1), (y0, y1) = span(map_x, camera.width), span(map_y, camera.height)
    if x1 - x0 < 2 or y1 - y0 < 2:   # the rays miss the frame: read it whole
        x0, x1, y0, y1 = 0, camera.width, 0, camera.height
    shifted = [(m - np.float32(o)).astype(np.float32) for m, o in ((map_x, x0), (map_y, y0))]
    for arr in shifted:
        arr.flags.writeable = False
    return (slice(y0, y1), slice(x0, x1)), shifted[0], shifted[1]


def ring_band_px(camera: CameraModel, plane_distance_mm: float,
                 plane_normal: np.ndarray | None = None, *, min_wall_mm: float,
                 max_wall_mm: float) -> tuple[float, float]:
    """Image radii (about the image of the optical axis) between which the ring can lie.

    The ring is where the laser plane {n·p = d} meets the wall, so it lies on the rays
    whose plane point is ``min_wall_mm`` to ``max_wall_mm`` from the probe axis; the
    band is those rays' image radii over every azimuth. Physical bounds (the probe
    body, a pipe the probe could be in) keep :func:`detect_ring` off the image
    centre (the mirror assembly) and the lens edge, where no ring can be.
    """
    normal = np.array([0.0, 0.0, 1.0]) if plane_normal is None else np.asarray(plane_normal,
                                                                                float)
    theta = np.linspace(0.0, camera.max_incidence_rad, 721)[1:]
    phi = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    rays = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    along = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(along > 1e-9, plane_distance_mm / along, np.inf)
    wall = t * np.sin(th)                  # the plane point's distance from the probe axis
    ok = (wall >= min_wall_mm) & (wall <= max_wall_mm)
    if not ok.any():
        raise ValueError(f"no ray meets the laser plane {min_wall_mm:g}-{max_wall_mm:g} mm "
                         f"from the probe axis")
    centre = ring_centre(camera)
    px = camera.project(rays[ok])
    radius = np.linalg.norm(px - centre, axis=1)
    radius = radius[np.isfinite(radius)]
    return float(radius.min()), float(radius.max())


def detect_ring(img: np.ndarray, camera: CameraModel, *, reflectance: np.ndarray | None = None,
                n_azimuths: int = 1440, band_px: tuple[float, float] | None = None,
                line_sigma_px: float | None = None, min_snr: float = 8.0,
                max_candidates: int = 3, min_relative: float = 0.2,
                occluded: np.ndarray | None = None) -> RingDetection:
    """Find laser-ring candidates in a laser frame.

    Parameters
    ----------
    img : numpy.ndarray
        Laser frame (8/16-bit or float, grey or colour) of the camera's size.
    camera : CameraModel
        Camera model (gives the image of the optical axis and the lens edge).
    reflectance : numpy.ndarray, optional
        The pair's LED frame. The laser line's brightness follows the wall's
        reflectance, and a reflectance gradient across the line shifts its centre
        (by gradient × width²: tenths of a pixel on a textured wall). Dividing by the
        LED frame, which sees the same wall, removes that bias.
    n_azimuths : int
        Number of polar rays.
    band_px : (float, float), optional
        Search only between these image radii about the image of the optical axis
        (:func:`ring_band_px`), widened by the ridge filter's reach; default: from the
        centre out to the lens edge.
    line_sigma_px : float, optional
        Expected Gaussian width of the laser line; default scales with the image.
    min_snr : float
        Minimum ridge strength in units of the noise of the ridge response.
    max_candidates : int
        Candidates kept per ray (the fit decides between them).
    min_relative : float
        Minimum ridge strength relative to the frame's typical ring response (the
        median over the rays of their strongest response); the maxima under it are
        returned apart, as ``fainter``.
    occluded : numpy.ndarray, optional
        True where the camera never sees the wall (probe.toml's mask:
        :func:`pipestitch.io.mask.read_mask`), camera-sized: no candidate there or on
        the sample next to it, and no centroid reaches into it.

    Returns
    -------
    RingDetection
        Possibly empty (no ring in the frame): check ``coverage``.
    """
    _check_frame("laser frame", img, camera)
    sigma = line_sigma_px or 2.0 * max(camera.width, camera.height) / 2448
    if band_px is not None:
        # Widened by the wide ridge Gaussian's kernel (16 sigma), so that the ridge of a
        # ring inside the band is what the whole ray would give; whole pixels (cache key).
        reach = 16 * sigma + 2
        band_px = (float(np.floor(band_px[0] - reach)), float(np.ceil(band_px[1] + reach)))
    search = functools.partial(_search_rays, img, reflectance, camera, laser_channel(img),
                               n_azimuths, band_px, sigma, occluded, min_snr=min_snr,
                               max_candidates=max_candidates, min_relative=min_relative)
    # Samples along a ray: two per expected line sigma (a 1224-px frame's 1-px line at
    # half-pixel steps, a 2448-px frame's 2-px line at whole pixels), never finer than
    # half a pixel (a small frame's thin line is sampled as a 1224-px frame's). A line
    # measured thinner than that sampling resolves is searched again at half-pixel steps
    # (one step for all such frames: the polar maps are cached by step).
    step = max(SAMPLES_MIN_STEP_PX, sigma / SAMPLES_PER_SIGMA)
    found = search(step=step)
    if step > SAMPLES_MIN_STEP_PX and found.line_sigma_px < RESAMPLE_BELOW * step:
        found = search(step=SAMPLES_MIN_STEP_PX)
    return found


SAMPLES_PER_SIGMA = 2.0     # polar samples per expected line sigma, along a ray
SAMPLES_MIN_STEP_PX = 0.5   # the finest sampling along a ray (px)
RESAMPLE_BELOW = 1.5        # a measured line sigma under this many samples: sampled again
BROAD_BOX_PX = 40.5         # the reflectance's broad mean: box length along a ray (px)


def _search_rays(img: np.ndarray, reflectance: np.ndarray | None, camera: CameraModel,
                 channel: int | None, n_azimuths: int, band_px: tuple[float, float] | None,
                 sigma: float, occluded: np.ndarray | None, *, step: float, min_snr: float,
                 max_candidates: int, min_relative: float) -> RingDetection:
    """:func:`detect_ring` at one sampling step along the rays.

    With the LED frame, the laser profile is divided by its reflectance; where the LED
    frame saw the wall shifted along the rays (the probe moved between the two frames:
    :func:`pipestitch.pose.pair_motion.led_shift`, measured on the ring found first),
    the ring is searched again with the reflectance read where the laser frame's wall
    is."""
    _, _, radii, centre = polar_grid(camera, n_azimuths, step, band_px)
    crop, map_x, map_y = polar_crop(camera, n_azimuths, step, band_px)
    part = np.asarray(img)[crop]
    # grey and the reflectance's temporaries do not outlive this call: scratch buffers
    grey = prepare_laser_frame(part, channel, out=scratch.buffer("ring.laser", part.shape[:2],
                                                                 np.float32))
    polar = cv2.remap(grey, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      dst=scratch.buffer("ring.polar", map_x.shape, np.float32))
    hidden = None if occluded is None else _polar_occluded(occluded, camera, n_azimuths, step,
                                                           band_px)
    search = functools.partial(_ring_search, sigma=sigma, step=step, hidden=hidden,
                               dtype=part.dtype, first_radius_px=radii[0], centre=centre,
                               n_azimuths=n_azimuths, min_snr=min_snr,
                               max_candidates=max_candidates, min_relative=min_relative)
    if reflectance is None:
        return search(polar)
    local = _led_polar(reflectance, channel, crop, map_x, map_y, camera)
    # A broad local mean: two passes of a 40-px box along the ray (~ a Gaussian of 16 px).
    box = 2 * round(BROAD_BOX_PX / step / 2) + 1
    found = search(flatten_by_reflectance(polar, local, box, 0.15, 0.15))
    shift = _led_shift(polar, local, found, radii[0], step, centre)
    if shift is None or not shift.moved:
        return replace(found, led_shift_px=math.nan if shift is None else 0.0)
    # the same division, by the LED frame read where the laser frame's wall is
    moved = flatten_by_moved_reflectance(polar, local, shift.along, shift.across, box,
                                         0.15, 0.15)
    return replace(search(moved), led_shift_px=float(np.mean(shift.along)) * step)


def _ring_search(polar: np.ndarray, *, sigma: float, step: float, hidden: np.ndarray | None,
                 dtype: np.dtype, first_radius_px: float, centre: np.ndarray, n_azimuths: int,
                 min_snr: float, max_candidates: int, min_relative: float) -> RingDetection:
    """The ring candidates of a polar laser profile (divided by the reflectance or not)."""
    # Ridge filter: a narrow Gaussian minus a wide one (in samples of `step` px). Both
    # in this thread's buffers, the same for each frame and both searches of a frame:
    # fresh frame-sized arrays each time cost the ring search a few per cent (1-5 %
    # measured; their memory traffic slows the steps around them too).
    narrow = _blur_along_rays(polar, sigma / step, "ring.narrow")
    wide = _blur_along_rays(polar, 4 * sigma / step, "ring.wide")
    ridge = np.subtract(narrow, wide, out=wide)   # in place: the wide blur is not read again
    noise = _ridge_noise(ridge, hidden, dtype)
    if hidden is not None:
        # No candidate where the camera never sees the wall, nor on a sample next to
        # it (NaN is neither above the floor nor above a neighbour): the peaks of what
        # lies there (a lit mirror mount, a glint on the arm) are not the ring's.
        ridge[hidden] = np.nan
    # Weak ridges are neither ring nor worth a candidate: keep the ridge maxima above
    # the noise and above a fraction of the typical ring response of this frame.
    strongest = np.max(ridge, axis=1) if hidden is None else np.fmax.reduce(ridge, axis=1)
    floor = min_snr * noise
    typical = float(median(strongest[strongest > floor])) if np.any(
        strongest > floor) else np.inf
    # A broad glint also has a ridge maximum; a thin line has a much larger ridge
    # response relative to its height, so rank by the response itself. The maxima
    # under the relative floor are kept apart (``fainter``): a ring can be much fainter
    # than a reflection in the same frame, whose response then sets the floor.
    order, top = ridge_peaks(ridge, floor, max_candidates)
    found = np.isfinite(top)
    strong = top > np.float64(max(floor, min_relative * typical))
    az_idx, rank = np.nonzero(strong)
    idx = order[az_idx, rank]
    width = _line_sigma_px(polar, az_idx[rank == 0], idx[rank == 0],
                           top[az_idx, rank][rank == 0] / noise, sigma / step) * step
    width = width if math.isfinite(width) else sigma   # too few candidates: as searched
    # The centroid spans the line as measured: a window of the expected width cut a
    # wider line (a thick or speckled one) near its brightest sample, pulling the
    # centre towards wherever that fell (ring-only tilt error 3.3 -> 2.3 deg on a
    # speckled line, 1.2 -> 0.8 deg on one 2.6 times as wide; docs/benchmarks.md).
    # At most the ridge filter's wide sigma (what the band's margin holds), and never
    # past half way to another candidate of the same ray (a ghost ring, a glint).
    line = min(max(width, sigma), 4 * sigma) / step
    located = functools.partial(_located, polar, narrow, order, top, line, hidden,
                                first_radius_px, step, centre, n_azimuths)
    fainter = located(found & ~strong, strong, noise, width, None, min_relative)
    return located(strong, strong, noise, width, fainter, min_relative)


def _led_shift(polar: np.ndarray, local: np.ndarray, found: RingDetection,
               first_radius_px: float, step: float, centre: np.ndarray) -> LedShift | None:
    """:func:`pipestitch.pose.pair_motion.led_shift` along the rays of the ring ``found``
    (its strongest candidate on each ray), searched over ``MAX_SHIFT_RADII`` of the
    ring's image radius; None when there is no ring or no shift."""
    best = found.rank == 0
    if not np.any(best):
        return None
    radius = np.hypot(*(found.pixels[best] - centre).T)
    at = np.clip(np.rint((radius - first_radius_px) / step).astype(np.int64), 0,
                 polar.shape[1] - 1)
    ring_px = float(np.median(radius))
    return led_shift(polar, local, found.azimuth[best], at, found.n_azimuths,
                     int(MAX_SHIFT_RADII * ring_px / step),
                     2 * math.pi * ring_px / found.n_azimuths / step)


def _located(polar: np.ndarray, narrow: np.ndarray, order: np.ndarray, top: np.ndarray,
             line: float, hidden: np.ndarray | None, first_radius_px: float, step: float,
             centre: np.ndarray, n_azimuths: int, chosen: np.ndarray, neighbours: np.ndarray,
             noise: float, width: float, fainter: RingDetection | None,
             relative: float) -> RingDetection:
    """The ``chosen`` ridge maxima (rays, rank) located to sub-sample precision, each
    centroid window kept half way to the ``neighbours`` of its ray (and off the
    samples that never see the wall)."""
    az_idx, rank = np.nonzero(chosen)
    idx = order[az_idx, rank]
    reach = _half_way_to_neighbours(order[az_idx], neighbours[az_idx] | chosen[az_idx], idx,
                                    3 * line)
    if hidden is not None:
        reach = np.minimum(reach, _clear_of(hidden, az_idx, idx, max(2, math.ceil(3 * line))))
    radius = _centroid(polar, narrow, az_idx, idx, line, reach) * step + first_radius_px
    phi = az_idx * (2 * np.pi / n_azimuths)
    pixels = np.stack([centre[0] + radius * np.cos(phi), centre[1] + radius * np.sin(phi)], 1)
    return RingDetection(pixels=pixels, azimuth=az_idx, rank=rank,
                         snr=top[az_idx, rank] / noise, n_azimuths=n_azimuths, noise=noise,
                         line_sigma_px=width, fainter=fainter, relative_floor=relative)


def _ridge_noise(ridge: np.ndarray, hidden: np.ndarray | None, dtype: np.dtype) -> float:
    """Noise of the ridge response (robust, from a subsample of the samples that see the
    wall), floored at a quarter of the frame's quantisation step (1/255 of full scale
    for 8-bit and float frames, 1/65535 for 16-bit ones) so that a noise-free frame
    does not turn every ripple into a candidate, while a 12-bit sensor's noise in a
    16-bit file is still its own."""
    sample = ridge[::3, ::3] if hidden is None else ridge[::3, ::3][~hidden[::3, ::3]]
    quantum = 1.0 / np.iinfo(dtype).max if dtype.kind in "ui" else 1.0 / 255
    noise = mad_sigma(sample)
    return max(noise, 0.25 * quantum) if math.isfinite(noise) else 0.25 * quantum


def _polar_occluded(occluded: np.ndarray, camera: CameraModel, n_azimuths: int, step: float,
                    band_px: tuple[float, float] | None) -> np.ndarray:
    """Which polar samples (:func:`polar_grid`) fall on a pixel that never sees the wall
    (``occluded``: True there); samples off the frame are not. A read-only mask (a run's:
    :class:`pipestitch.pipeline.posing.PoseSettings`) is resampled once (~2 ms a frame
    otherwise) and cached by identity."""
    _check_frame("occluder mask", occluded, camera)
    occluded = np.asarray(occluded, bool)   # the same array when it is one of booleans
    if occluded.flags.writeable:
        return _resampled(_Same(occluded), camera, n_azimuths, step, band_px)
    return _resampled_cached(_Same(occluded), camera, n_azimuths, step, band_px)


class _Same:
    """An array as a cache key: equal to itself only (the cache holds it, so its id is
    not reused while cached)."""

    def __init__(self, array: np.ndarray) -> None:
        self.array = array

    def __hash__(self) -> int:
        return id(self.array)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Same) and other.array is self.array


def _resampled(occluded: _Same, camera: CameraModel, n_azimuths: int, step: float,
               band_px: tuple[float, float] | None) -> np.ndarray:
    map_x, map_y, _, _ = polar_grid(camera, n_azimuths, step, band_px)
    # nearest pixel: a sample is hidden when the pixel it falls on is
    polar = cv2.remap(np.asarray(occluded.array, np.uint8), map_x, map_y, cv2.INTER_NEAREST,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0).view(bool)
    polar.flags.writeable = False
    return polar


_resampled_cached = functools.lru_cache(maxsize=4)(_resampled)


def _clear_of(hidden: np.ndarray, rows: np.ndarray, idx: np.ndarray, half: int) -> np.ndarray:
    """Per candidate, how many samples its centroid window may reach on either side
    before the first hidden sample of its ray within ``half`` (inf when none)."""
    offsets = np.arange(-half, half + 1)
    at = np.clip(idx[:, None] + offsets, 0, hidden.shape[1] - 1)
    near = np.where(hidden[rows[:, None], at], np.abs(offsets), np.inf)
    return near.min(axis=1) - 1.0


FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
MIN_WIDTH_SAMPLES = 12   # strongest candidates needed to measure the line's width


def _line_sigma_px(polar: np.ndarray, rows: np.ndarray, idx: np.ndarray, snr: np.ndarray,
                   sigma_samples: float) -> float:
    """The laser line's Gaussian sigma (in polar samples) from its half-maximum width.

    Measured on the unfiltered profile of the strongest half of the rays' best
    candidates: background the 20th percentile of a window of +-8 expected sigmas (wide
    enough for a line several times wider than expected), the half-maximum crossings
    interpolated linearly on both sides of the peak
    (:func:`pipestitch.pose._ring_kernels.line_widths`). The median over the rays is
    what a frame's scales are taken from (:func:`pipestitch.pose.fit.fit_pose`): the
    line's width sets how exactly its centre can be found. NaN with fewer than
    ``MIN_WIDTH_SAMPLES`` candidates.
    """
    if rows.size < MIN_WIDTH_SAMPLES:
        return float("nan")
    strong = snr >= median(snr)
    half = max(4, int(np.ceil(8 * sigma_samples)))
    fwhm = line_widths(polar, rows[strong], idx[strong], half)
    fwhm = fwhm[~np.isnan(fwhm)]
    if fwhm.size < MIN_WIDTH_SAMPLES // 2:
        return float("nan")
    return float(median(fwhm)) / FWHM_PER_SIGMA


def _check_frame(what: str, img: np.ndarray, camera: CameraModel) -> None:
    """Raise ValueError, naming ``what``, unless ``img`` is a grey or colour image of the
    camera's size."""
    shape = np.shape(img)
    if len(shape) not in (2, 3):
        raise ValueError(f"{what}: expected a 2-D or 3-D image, got shape {shape}")
    if shape[:2] != (camera.height, camera.width):
        raise ValueError(f"{what}: expected {camera.width}x{camera.height}, "
                         f"got {shape[1]}x{shape[0]}")


def _blur_along_rays(polar: np.ndarray, sigma: float, key: str) -> np.ndarray:
    """Gaussian blur along each ray (axis 1) only, over +-4 sigma
    (:func:`pipestitch.imaging.gaussian_blur`), into this thread's buffer ``key``
    (:func:`pipestitch._runtime.scratch.buffer`: valid until the next call with it)."""
    return gaussian_blur(polar, sigma, along_rows=True, taps=2 * int(np.ceil(4 * sigma)) + 1,
                         border=cv2.BORDER_REPLICATE,
                         out=scratch.buffer(key, polar.shape, np.float32))


def _led_polar(reflectance: np.ndarray, channel: int | None, crop: tuple[slice, slice],
               map_x: np.ndarray, map_y: np.ndarray, camera: CameraModel) -> np.ndarray:
    """The LED frame on the rays' polar grid, in the laser's channel: the wall's
    reflectance that the laser profile is divided by
    (:func:`pipestitch.pose._ring_kernels.flatten_by_reflectance`: normalised by its own
    broad average along each ray, LED fall-off and vignetting, so that only the local
    reflectance remains; where the wall is too dark to measure, holes or black paint,
    the laser carries no usable signal and is zeroed)."""
    _check_frame("reflectance", reflectance, camera)
    # the wall as the laser's channel sees it (over the crop the maps read)
    part = np.asarray(reflectance)[crop]
    led = prepare_laser_frame(part, channel,
                              out=scratch.buffer("ring.led", part.shape[:2], np.float32))
    led = cv2.GaussianBlur(led, (0, 0), 0.5, dst=scratch.buffer("ring.led_blur", led.shape,
                                                                np.float32))
    return cv2.remap(led, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     dst=scratch.buffer("ring.local", map_x.shape, np.float32))


def _half_way_to_neighbours(others: np.ndarray, found: np.ndarray, idx: np.ndarray,
                            apart: float) -> np.ndarray:
    """Per candidate, half the distance (samples) to the nearest other candidate of its
    ray at least ``apart`` away (inf when there is none). ``others``: the ray's
    candidate samples (n, count), ``found``: which of them are candidates, ``idx``: the
    candidate's own sample. Maxima closer than ``apart`` (three line sigmas where
    :func:`detect_ring` asks) are the same line's (speckle, a flat top), not a
    neighbour."""
    gap = np.abs(others - idx[:, None]).astype(float)
    gap[~found | (gap < apart)] = np.inf
    return np.floor(gap.min(axis=1) / 2)


def _centroid(polar: np.ndarray, smooth: np.ndarray, rows: np.ndarray, idx: np.ndarray,
              sigma_samples: float, reach: np.ndarray | None = None) -> np.ndarray:
    """Sub-sample peak position: centroid of the profile above its local background.

    The window spans +-3 ``sigma_samples`` (the line's sigma), each candidate's cut to
    +-``reach`` samples where given; the background is the lower of the window's two
    end values, so a sloping background (LED leakage, the far-wall glow) is not
    mistaken for signal. Saturated (flat-topped) peaks are handled correctly, which a
    parabola fit is not. (:func:`pipestitch.pose._ring_kernels.centroids`.)
    """
    half = max(2, int(np.ceil(3 * sigma_samples)))
    if reach is None:
        reach = np.full(len(idx), np.inf)
    # one compiled signature: C-ordered indices (np.nonzero's rows of a 2-D array are not)
    return centroids(polar, smooth, np.ascontiguousarray(rows), np.ascontiguousarray(idx), half,
                     np.ascontiguousarray(reach, np.float64))
