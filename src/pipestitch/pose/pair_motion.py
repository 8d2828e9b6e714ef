"""How far the LED frame's wall lies from the laser frame's along the ring's rays.

The probe moves a little between the two frames of a pair (SPEC): an axial motion of
1 mm moves the wall's image at the ring by ~8 px in a 1224-px frame of a 65 mm pipe.
The ring search divides the laser profile by the wall's reflectance seen in the LED
frame (:func:`pipestitch.pose.ring.detect_ring`); read where the LED frame saw another
stretch of wall, the division puts texture into the line instead of taking it out,
and the ring-only tilt was 0.75 deg off (median, 3.9 deg at worst) where it was
0.15 deg with the frames taken at one position.

The laser line's brightness along the ring follows the wall's reflectance under it.
So the LED frame's shift along the rays is the one at which its reflectance, read
along the ring moved by that shift, correlates best with the line's brightness
(both high-passed along the ring, logarithms: the illumination's slow fall-off
multiplies both). It is found for the whole ring first, then measured in sectors of
the ring along and across the rays and fitted with a constant and a first harmonic
each (the axial motion moves the near wall's image more than the far wall's when the
probe is off-centre; a sideways motion, a change of tilt and a roll move it across the
rays). Where no shift correlates clearly better than none, either the frames were taken
together (the correlation peaks at no shift, clearly above every shift outside that
peak) or the wall shows too little texture under the line to tell (anything else).

Why hand-written: no library measures a shift along a set of rays from a line's
brightness; the correlations are sums over each sector's rays, one compiled pass
(:func:`pipestitch.pose._pair_motion_kernels.sector_correlations`).

Pure: polar samples in, a shift per ray (samples) out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from pipestitch.pose import _pair_motion_kernels as _k

F32 = np.float32

__all__ = ["MAX_SHIFT_RADII", "LedShift", "led_shift"]

SECTORS = 8              # the ring's sectors, each measured alone
MIN_SECTOR_RAYS = 15     # rays with a ring point a sector needs to be measured
HIGH_PASS_RAYS = 15      # the running mean taken off along the ring (rays)
SIGNIFICANT = 3.0        # standard errors of a correlation by which a shift must beat 0
# ... and the reflectance moved must explain at least a quarter of the variance of the
# line's brightness along the ring: a line that is not on the wall (a glowing mirror
# mount found first) correlates with the wall by chance only (0.16 where a ring taken
# 1-2.5 mm before its LED frame correlates 0.72-0.87)
MIN_CORRELATION = 0.5
MAX_SHIFT_RADII = 0.25   # the search reaches this share of the ring's image radius
WITHIN_MEAN = 0.5        # a sector's shift is within this share of the mean shift of it
COARSE = 2               # the first search takes every COARSE-th shift (samples); both
                         # searches every COARSE-th ray
# ... and smooths both sides along the ring over this many of its rays, so that a wall
# also turned by a few rays (a sideways motion, a roll) still correlates
COARSE_SMOOTH = 5


def led_shift(laser: np.ndarray, led: np.ndarray, rays: np.ndarray, at: np.ndarray,
              n_azimuths: int, max_shift: int, samples_per_ray: float) -> LedShift | None:
    """Where the LED frame shows the wall the laser frame shows on the ring: its shift
    along each ray and across the rays, or None where no shift is measured.

    Parameters
    ----------
    laser, led : numpy.ndarray, shape (n_azimuths, n_samples), float32
        The laser frame and the LED frame on the same polar grid (rays by row).
    rays, at : numpy.ndarray of int
        The ring: a ray (increasing) and the sample of the line's peak on it.
    n_azimuths : int
        Rays of the grid.
    max_shift : int
        Largest shift along the rays looked for (samples).
    samples_per_ray : float
        The distance between neighbouring rays at the ring, in samples along a ray.

    Returns
    -------
    LedShift or None
        No shift on any ray where the wall says the frames were taken together
        (:func:`_still`); None where it cannot tell (too few rays, too little texture
        under the line, no clear best shift).
    """
    sectors = rays * SECTORS // n_azimuths
    counts = np.bincount(sectors, minlength=SECTORS)
    if rays.size < MIN_SECTOR_RAYS or max_shift < 1:
        return None
    # The whole ring first, every COARSE-th shift on every COARSE-th ray: one stretch
    # of wall (a stain, a pit) can make a sector's correlation peak anywhere; the
    # sectors together peak at the pair's motion.
    coarse = np.arange(-(max_shift // COARSE), max_shift // COARSE + 1) * COARSE
    every = slice(None, None, COARSE)
    rays, at, sectors = rays[every], at[every], sectors[every]
    corr = _correlations(_brightness(laser, rays, at, COARSE_SMOOTH), led, rays, at, sectors,
                         coarse, np.zeros(1, np.int64), COARSE_SMOOTH)[:, 0]
    seen = np.all(np.isfinite(corr), axis=1)
    if np.count_nonzero(seen) < 3:
        return None
    weight = counts[seen] / counts[seen].sum()
    total = weight @ corr[seen]
    best, zero = int(np.argmax(total)), coarse.size // 2
    error = weight @ ((1.0 - np.clip(corr[seen, best], -1.0, 1.0) ** 2)
                      / np.sqrt(np.maximum(counts[seen] // COARSE - 3, 1)))
    if total[best] < MIN_CORRELATION or total[best] - total[zero] <= SIGNIFICANT * error:
        still = abs(best - zero) <= 1 and _still(total, zero, error)
        return LedShift.constant(n_azimuths, 0.0, 0.0) if still else None
    # Then every shift near it, along and across the rays, each sector alone: the
    # motion moves the near wall's image more than the far wall's (an off-centre
    # probe), and a sideways motion or a roll turns it, by less than half the mean shift.
    half = max(COARSE, int(np.ceil(WITHIN_MEAN * abs(coarse[best])))) + COARSE
    along = np.arange(coarse[best] - half, coarse[best] + half + 1)
    reach = int(np.ceil(WITHIN_MEAN * half / samples_per_ray))   # a turn moves less
    across = np.arange(-reach, reach + 1)
    corr = _correlations(_brightness(laser, rays, at), led, rays, at, sectors, along,
                         across)                                 # (sector, across, along)
    kept, found = _sector_peaks(corr, seen)
    if np.count_nonzero(kept) < 4:   # too few sectors: the ring's mean shift only
        middle = np.unravel_index(np.argmax(weight @ np.nan_to_num(
            corr[seen].reshape(np.count_nonzero(seen), -1))), corr.shape[1:])
        peak = _peak_offsets(weight @ np.nan_to_num(corr[seen, middle[0]]), middle[1])
        return LedShift.constant(n_azimuths, along[middle[1]] + peak, across[middle[0]])
    centres = (np.arange(SECTORS) + 0.5) * (2 * math.pi / SECTORS)
    design = np.column_stack([np.ones(SECTORS), np.cos(centres), np.sin(centres)])[kept]
    shift = np.linalg.lstsq(design, along[0] + found[kept, 1], rcond=None)[0]
    turn = np.linalg.lstsq(design, across[0] + found[kept, 0], rcond=None)[0]
    phi = np.arange(n_azimuths) * (2 * math.pi / n_azimuths)
    harmonics = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    # within the window searched: the sectors kept may all lie on one side of the ring
    return LedShift(np.clip(harmonics @ shift, along[0], along[-1]),
                    np.clip(harmonics @ turn, across[0], across[-1]))


@dataclass(frozen=True)
class LedShift:
    """Where each ray's wall is in the LED frame: ``along`` samples further out on ray
    ``r + across[r]`` (fractional rays) than on ray ``r`` of the laser frame."""

    along: np.ndarray
    across: np.ndarray

    @classmethod
    def constant(cls, n_azimuths: int, along: float, across: float) -> LedShift:
        """The same shift for every ray."""
        return cls(np.full(n_azimuths, float(along)), np.full(n_azimuths, float(across)))

    @property
    def moved(self) -> bool:
        """Whether any ray's wall moved (False: the frames were taken together)."""
        return bool(np.any(self.along != 0) or np.any(self.across != 0))

    def apply(self, polar: np.ndarray) -> np.ndarray:
        """``polar`` (an LED frame on the rays) read where the laser frame's wall is
        (linear interpolation; rays wrap around, a ray's ends are repeated beyond it)."""
        n_rays, n = polar.shape
        pad = int(np.ceil(np.max(np.abs(self.across)))) + 1
        wrapped = np.concatenate([polar[-pad:], polar, polar[:pad]])
        cols = np.arange(n, dtype=np.float32)[None, :] + self.along.astype(np.float32)[:, None]
        rows = (np.arange(n_rays) + pad + self.across).astype(np.float32)
        return cv2.remap(wrapped, cols, np.ascontiguousarray(np.broadcast_to(rows[:, None],
                                                                              cols.shape)),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _still(total: np.ndarray, zero: int, error: float) -> bool:
    """Whether the whole ring's correlation over the shifts (``total``, no shift at
    ``zero``), which peaks there (within one coarse step), says the LED frame saw
    the wall where the laser frame did: at no shift at least ``MIN_CORRELATION``,
    and above every shift outside its own peak (beyond where it first falls to half
    of that on either side) by ``SIGNIFICANT`` standard errors (``error``). A wall
    with too little texture under the line correlates weakly or alike at every
    shift: it cannot tell (0.22-0.46 at no shift on brushed aluminium and a wall
    with a lit arm, 0.94-0.98 on a corroded wall, a test chart, an oval pipe with
    the frames taken together)."""
    if total[zero] < MIN_CORRELATION:
        return False
    low = total < 0.5 * total[zero]
    before, after = np.flatnonzero(low[:zero]), np.flatnonzero(low[zero:])
    if not before.size or not after.size:   # a peak as wide as the search
        return False
    far = np.concatenate([total[:before[-1] + 1], total[zero + after[0]:]])
    return bool(total[zero] - far.max() > SIGNIFICANT * error)


def _sector_peaks(corr: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each sector's correlation peak over (across, along): the sectors whose peak is
    inside the searched window, and the peaks (sub-sample, from the window's first
    row and column)."""
    n_sectors, n_across, n_along = corr.shape
    flat = np.argmax(np.nan_to_num(corr.reshape(n_sectors, -1), nan=-2.0), axis=1)
    i, j = np.unravel_index(flat, (n_across, n_along))
    kept = seen & (i > 0) & (i < n_across - 1) & (j > 0) & (j < n_along - 1)
    found = np.zeros((n_sectors, 2))
    for k in np.flatnonzero(kept):
        found[k] = (i[k] + _peak_offsets(corr[k, :, j[k]], i[k]),
                    j[k] + _peak_offsets(corr[k, i[k]], j[k]))
    return kept, found


def _brightness(laser: np.ndarray, rays: np.ndarray, at: np.ndarray,
                smooth: int = 1) -> np.ndarray:
    """The line's brightness along the ring, as :func:`_correlations` takes it (log,
    high-passed along the ring, smoothed over ``smooth`` rays)."""
    return _high_pass(np.log(np.maximum(laser[rays, at], F32(1e-6)))[None, :], smooth)[0]


def _correlations(line: np.ndarray, led: np.ndarray, rays: np.ndarray, at: np.ndarray,
                  sectors: np.ndarray, shifts: np.ndarray, turns: np.ndarray,
                  smooth: int = 1) -> np.ndarray:
    """(SECTORS, turns, shifts) correlation of the line's brightness along the ring
    (``line``: :func:`_brightness` with the same ``smooth``) with the LED frame's
    reflectance along the ring moved by each shift along the rays and each turn (rays)
    across them (logarithms, high-passed along the ring; the LED frame's ends of a ray
    repeated beyond it); NaN where a sector has too few rays. ``sectors`` must not
    decrease (the rays increase). The logarithms are taken once, over the samples the
    shifts reach on the rays read (numpy's vectorised log: the values it gives each
    sample alone), and read by
    :func:`pipestitch.pose._pair_motion_kernels.sector_correlations`."""
    count = np.bincount(sectors, minlength=SECTORS)
    bounds = np.searchsorted(sectors, np.arange(SECTORS + 1))
    line = line.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        centred = line - (np.bincount(sectors, line, SECTORS) / count)[sectors]
        spread = np.bincount(sectors, centred * centred, SECTORS) / count
    n_rays, n = led.shape
    first = int(np.clip(at.min() + shifts.min(), 0, n - 1))
    last = int(np.clip(at.max() + shifts.max(), 0, n - 1))
    read = (rays[None, :] + turns[:, None]) % n_rays
    if turns.size == 1:   # the rays of the ring only (one per row)
        logs, read = led[read[0], first:last + 1], np.arange(rays.size)[None, :]
    else:
        logs = led[:, first:last + 1]
    logs = np.maximum(logs, F32(1e-6))
    np.log(logs, out=logs)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = _k.sector_correlations(logs, first, n, read.astype(np.int64),
                                     at.astype(np.int64), bounds, centred, spread,
                                     shifts.astype(np.int64), HIGH_PASS_RAYS, smooth)
    out[count < MIN_SECTOR_RAYS] = np.nan
    return out


def _high_pass(values: np.ndarray, smooth: int = 1) -> np.ndarray:
    """Each row less its running mean over ``HIGH_PASS_RAYS`` neighbours (float32), then
    its running mean over ``smooth`` neighbours."""
    values = np.ascontiguousarray(values, np.float32)
    out = values - cv2.blur(values, (HIGH_PASS_RAYS, 1), borderType=cv2.BORDER_REFLECT)
    return cv2.blur(out, (smooth, 1), borderType=cv2.BORDER_REFLECT) if smooth > 1 else out


def _peak_offsets(curve: np.ndarray, at: int) -> float:
    """Sub-sample offset of the peak of ``curve`` at index ``at`` (a parabola through it
    and its two neighbours; 0 at the ends or where they are missing)."""
    if not 0 < at < curve.size - 1:
        return 0.0
    y0, y1, y2 = curve[at - 1:at + 2]
    bend = y0 - 2 * y1 + y2
    return float(0.5 * (y0 - y2) / bend) if np.isfinite(bend) and bend < 0 else 0.0


