"""Where the laser ring leaves the fitted pipe section: a dent, a deposit, a bulge.

The pose fit keeps the ring points that lie on one section of a cylinder (a circle or
an oval) and drops the rest as outliers, so a wall pushed in over part of its
circumference leaves the fit (and the pose) alone, and shows only as rays without an
inlier. Those rays' candidates are looked at here: each candidate is put on the wall
with the fitted pose (the laser plane's point seen along its pixel's ray) and its
distance from the pipe axis compared with the section's radius there. A stretch of
rays whose strongest such departure exceeds the fit's own inlier gate, with the same
sign, and that rises out of the ring at both ends (not a separate curve next to it, as
a glint or a reflection would be), is a departure of the wall.

Pure and vectorised: candidates, pose and section in, one :class:`Departure` or None
out. Both mirror hypotheses give the same ring conic, hence the same radii; only the
angle of the departure differs (each hypothesis' own world frame).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose
from pipestitch.pose.fit import GATE_SIGMAS, LaserPlane, plane_points, plane_to_world
from pipestitch.pose.ring import RingDetection

__all__ = ["BAND_RADII", "MIN_DEPTH_GATES", "MIN_EXTENT_DEG", "Departure", "ring_departures"]

BAND_RADII = 0.25      # candidates further than this share of the radius are not the wall
MIN_EXTENT_DEG = 6.0   # narrower stretches are not reported (a hole's edge: the mosaic's)
MIN_DEPTH_GATES = 2.0  # nor shallower ones: their extreme beyond this many inlier gates
SMOOTH_RAYS = 5        # running median along the rays: one stray candidate is not a dent
EDGE_GATES = 3.0       # a departure rises out of the ring: its ends within this many gates
MIN_FILL = 0.8         # ... is seen on this share of its rays at least
SCATTER_SIGMAS = 2.0   # ... and scatters about its running median by at most this (median)


@dataclass(frozen=True, slots=True)
class Departure:
    """The largest stretch of the ring off the fitted section.

    Attributes
    ----------
    depth_mm : float
        Signed radial departure at its extreme: negative inward (a dent, a deposit),
        positive outward (a bulge, a groove).
    theta_deg : float
        Angle of that extreme about the pipe axis, in the hypothesis' world frame
        (degrees, 0-360, SPEC's pipe frame: roll not applied).
    extent_deg : float
        Angular extent of the stretch (degrees).
    min_radius_mm, max_radius_mm : float
        Smallest and largest wall radius the ring measured over its whole circumference
        (the section's radius where the ring follows it).
    """

    depth_mm: float
    theta_deg: float
    extent_deg: float
    min_radius_mm: float
    max_radius_mm: float


def ring_departures(detection: RingDetection, hypotheses: Sequence[tuple[Pose, PipeSection]],
                    camera: CameraModel, plane: LaserPlane, noise_mm: float,
                    ) -> tuple[Departure | None, ...]:
    """The ring's largest departure from each hypothesis' section, or None for one.

    Parameters
    ----------
    detection : RingDetection
        The frame's ring candidates (:func:`pipestitch.pose.ring.detect_ring`).
    hypotheses : sequence of (Pose, PipeSection)
        Fitted hypotheses and their sections (the candidates are put on the laser plane
        once for all of them).
    camera : CameraModel
        Camera model.
    plane : LaserPlane
        The laser plane.
    noise_mm : float
        The fit's point noise on the plane: departures beyond ``GATE_SIGMAS`` of it (the
        fit's inlier gate) count.
    """
    uv, valid = plane_points(detection.pixels, camera, plane.distance_mm, plane.normal)
    if len(uv) == 0:
        return tuple(None for _ in hypotheses)
    out = []
    for pose, section in hypotheses:
        a, c = plane_to_world(pose, plane)
        xy = uv @ np.asarray(a).T + np.asarray(c)
        out.append(_departure(detection, xy, valid, section, noise_mm))
    return tuple(out)


def _departure(detection: RingDetection, xy: np.ndarray, valid: np.ndarray,
               section: PipeSection, noise_mm: float) -> Departure | None:
    """:func:`ring_departures` of one hypothesis: its candidates' world ``xy``."""
    n_az = detection.n_azimuths
    min_rays = max(3, math.ceil(MIN_EXTENT_DEG / 360.0 * n_az))
    delta = _ray_departures(detection, xy, valid, section)
    smooth = _running_median(delta, SMOOTH_RAYS)
    gate = GATE_SIGMAS * noise_mm
    runs = [(start, stop) for start, stop in _runs(np.abs(smooth) > gate, np.sign(smooth))
            if stop - start >= min_rays and _rises_from_ring(smooth, start, stop, gate)
            and _continuous(delta, smooth, np.arange(start, stop) % n_az, noise_mm)]
    rays = [r for r in (np.arange(start, stop) % n_az for start, stop in runs)
            if np.nanmax(np.abs(smooth[r])) >= MIN_DEPTH_GATES * gate]
    if not rays:
        return None
    extremes = [r[int(np.argmax(np.abs(smooth[r])))] for r in rays]
    k = int(np.argmax([abs(smooth[e]) for e in extremes]))
    angle = _ray_angles(detection, xy, valid)
    theta = math.degrees(angle[extremes[k]]) % 360.0
    # the wall the ring measured: the section, and where the ring departs from it
    departing = np.zeros(n_az, bool)
    departing[np.concatenate(rays)] = True
    wall = _section_radius(section, angle) + np.where(departing, smooth, 0.0)
    return Departure(float(smooth[extremes[k]]), theta, 360.0 * len(rays[k]) / n_az,
                     float(np.nanmin(wall)), float(np.nanmax(wall)))


def _ray_departures(detection: RingDetection, xy: np.ndarray, valid: np.ndarray,
                    section: PipeSection) -> np.ndarray:
    """Per ray, the departure (mm) of its candidate (world ``xy``; ``valid`` says which
    candidates have one) nearest the section, NaN without one within ``BAND_RADII``."""
    theta = np.arctan2(xy[:, 1], xy[:, 0])
    off = np.hypot(xy[:, 0], xy[:, 1]) - section.radius_at(theta)
    ray = detection.azimuth[valid]
    near = np.abs(off) <= BAND_RADII * section.mean_radius_mm
    out = np.full(detection.n_azimuths, np.inf)
    np.minimum.at(out, ray[near], np.abs(off[near]))
    signed = np.full(detection.n_azimuths, np.nan)
    chosen = near & (np.abs(off) == out[ray])
    signed[ray[chosen]] = off[chosen]
    return signed


def _ray_angles(detection: RingDetection, xy: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per ray, the world angle (rad) of its strongest candidate (rays without one:
    between their neighbours)."""
    angle = np.full(detection.n_azimuths, np.nan)
    strongest = detection.rank[valid] == 0
    angle[detection.azimuth[valid][strongest]] = np.arctan2(xy[strongest, 1], xy[strongest, 0])
    known = np.isfinite(angle)
    if known.sum() >= 2:   # rays without a candidate: between their neighbours
        rays = np.arange(detection.n_azimuths)
        cos, sin = (np.interp(rays, rays[known], f(angle[known]), period=detection.n_azimuths)
                    for f in (np.cos, np.sin))
        angle = np.arctan2(sin, cos)
    return angle


def _section_radius(section: PipeSection, angle: np.ndarray) -> np.ndarray:
    radius = np.full(angle.shape, np.nan)
    known = np.isfinite(angle)
    radius[known] = section.radius_at(angle[known])
    return radius


def _running_median(values: np.ndarray, width: int) -> np.ndarray:
    """Circular running median over ``width`` rays, ignoring NaN (NaN where all are)."""
    half = width // 2
    stack = np.stack([np.roll(values, k) for k in range(-half, half + 1)])
    out = np.full(values.shape, np.nan)
    some = np.isfinite(stack).any(axis=0)
    out[some] = np.nanmedian(stack[:, some], axis=0)
    return out


def _runs(mask: np.ndarray, sign: np.ndarray) -> list[tuple[int, int]]:
    """Circular runs [start, stop) of ``mask`` with one sign; stop may exceed the length."""
    n = len(mask)
    if mask.all():
        return [(0, n)] if len(set(sign[mask].tolist())) == 1 else []
    first = int(np.flatnonzero(~mask)[0])   # start scanning just after a gap
    runs, start = [], None
    for step in range(1, n + 1):
        k = (first + step) % n
        inside = mask[k] and (start is None or sign[k] == sign[start % n])
        if inside and start is None:
            start = first + step
        elif not inside and start is not None:
            runs.append((start, first + step))
            start = first + step if mask[k] else None
    if start is not None:
        runs.append((start, first + n + 1))
    return runs


def _rises_from_ring(smooth: np.ndarray, start: int, stop: int, gate: float) -> bool:
    """Whether the stretch [start, stop) leaves the ring continuously: the nearest
    measured rays beyond both ends lie on the section (within the gate) and its own
    end rays within ``EDGE_GATES`` gates (a separate curve starts and ends at its full
    offset, or next to rays without a candidate)."""
    n = len(smooth)
    ends = [smooth[start % n], smooth[(stop - 1) % n]]
    outside = [_nearest_measured(smooth, start - 1, -1), _nearest_measured(smooth, stop, 1)]
    return (all(v is not None and abs(v) <= gate for v in outside)
            and all(abs(v) <= EDGE_GATES * gate for v in ends))


def _continuous(delta: np.ndarray, smooth: np.ndarray, rays: np.ndarray,
                noise_mm: float) -> bool:
    """Whether the rays ``rays`` hold one continuous curve: a candidate on at least
    ``MIN_FILL`` of them, scattering about their running median by no more than
    ``SCATTER_SIGMAS`` point sigmas (median absolute). Where the ring crosses a hole or
    a glint, candidates are missing and jump from ray to ray."""
    measured = np.isfinite(delta[rays])
    if measured.mean() < MIN_FILL:
        return False
    scatter = float(np.median(np.abs(delta[rays] - smooth[rays])[measured]))
    return scatter <= SCATTER_SIGMAS * noise_mm


def _nearest_measured(values: np.ndarray, k: int, step: int, reach: int = 3) -> float | None:
    n = len(values)
    for i in range(reach):
        v = values[(k + i * step) % n]
        if np.isfinite(v):
            return float(v)
    return None
