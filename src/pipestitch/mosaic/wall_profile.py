"""The wall's radius along the run from the laser rings, for strips that reach past
their own ring (a reducer, a long dent, a weld bead).

Each strip is unwrapped onto a wall; with its own ring's section alone that wall is a
cylinder, and where the pipe's radius changes inside the strip's window the strip's
axial scale is off by about as much (a 2.5 mm narrowing seen 12 mm from the ring:
~4 %), and so are the registration's steps and z. The rings of the other frames
measure the radius where they are: placed by the frames' z, they give each strip the
wall it sees (:class:`~pipestitch.geometry.RadiusProfile`, in the frame's own z).

Which differences are real is taken from the rings themselves: their scatter along
the run (second differences of the radii in z order, a robust spread) is the noise a
difference must clear.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pipestitch.geometry import RadiusProfile
from pipestitch.imaging import mad_sigma

__all__ = ["SIGNIFICANCE", "frame_profiles", "ring_radius_noise"]

SIGNIFICANCE = 4.0   # a strip gets a profile where the wall it sees differs by this many sigmas


def ring_radius_noise(radius_mm: np.ndarray) -> float:
    """Robust spread (mm) of one ring's radius from the radii of rings in z order.

    The second difference of three neighbours holds 6 times a ring's variance; its
    median absolute deviation (scaled to a sigma) ignores the few steps where the
    pipe's radius really turns (a reducer's ends). NaN with fewer than 4 rings.
    """
    r = np.asarray(radius_mm, float)
    if r.size < 4:
        return float("nan")
    return float(mad_sigma(np.diff(r, 2)) / np.sqrt(6.0))


def _merged(ring_z_mm: np.ndarray, radius_mm: np.ndarray, tol_mm: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Rings in z order, those closer than ``tol_mm`` (a probe standing or reversing)
    averaged into one point, so the profile's z increase."""
    order = np.argsort(ring_z_mm, kind="stable")
    z, r = ring_z_mm[order], radius_mm[order]
    group = np.concatenate([[0], np.cumsum(np.diff(z) > tol_mm)])
    count = np.bincount(group)
    return np.bincount(group, z) / count, np.bincount(group, r) / count


def frame_profiles(camera_z_mm: Mapping[int, float], radius_mm: Mapping[int, float],
                   ring_ahead_mm: float, window_mm: tuple[float, float], *,
                   step_mm: float) -> dict[int, RadiusProfile]:
    """The wall each frame's strip sees, where it differs from the frame's own ring.

    Parameters
    ----------
    camera_z_mm : mapping
        Frame -> its camera's axial position (mm) in the run.
    radius_mm : mapping
        Frame -> its ring's mean radius (mm): the section its strip is unwrapped onto.
    ring_ahead_mm : float
        How far ahead of the camera the ring lies (the laser plane distance).
    window_mm : (float, float)
        The strips' axial window about their camera.
    step_mm : float
        The strips' axial grid step: rings closer than this along the pipe are one
        measurement, and a difference that would move the window's ends by less than a
        quarter of it is left alone.

    Returns
    -------
    dict
        Frame -> profile in its own z (0 at its camera; scale 1 at its ring, or the
        mean of the rings merged with it over its own radius there), for the
        frames whose window holds a ring differing from their own by more than
        ``SIGNIFICANCE`` times the difference's noise (and than that quarter step).
        Empty with fewer than 4 rings.
    """
    frames = [i for i in radius_mm if np.isfinite(camera_z_mm.get(i, np.nan))
              and np.isfinite(radius_mm[i])]
    if len(frames) < 4:
        return {}
    own = np.array([radius_mm[i] for i in frames])
    z_ring = np.array([camera_z_mm[i] for i in frames]) + ring_ahead_mm
    z, r = _merged(z_ring, own, step_mm)
    noise = ring_radius_noise(r)
    if not np.isfinite(noise) or z.size < 2:
        return {}
    length = window_mm[1] - window_mm[0]
    out: dict[int, RadiusProfile] = {}
    for i, radius in zip(frames, own, strict=True):
        gate = max(SIGNIFICANCE * np.sqrt(2.0) * noise, radius * step_mm / (4 * length))
        local = z - camera_z_mm[i]
        inside = (local >= window_mm[0]) & (local <= window_mm[1])
        if np.any(np.abs(r[inside] - radius) > gate):
            out[i] = RadiusProfile(local, r / radius)
    return out
