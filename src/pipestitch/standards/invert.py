"""Find the invert on the mosaic from a sediment band or the wetted strip below a water
line: a band of rows (theta) that is darker or brighter than the rest of the wall in
(almost) every column along the pipe.

Hand-written because it is a few lines of robust statistics on the row profile; the
band must be wide (>= 20 deg: narrower persistent strips are e.g. the laser-holder
arm's shadow), present along the run (>= 80 % of the columns), so holes, spots and
texture do not make one, and bounded by an edge on both sides: across each of its
edges the profile steps by at least half the band's contrast within a few degrees.
A smooth swell of brightness around the circumference (the LEDs lighting the near
wall more than the far one, an uneven coating) crosses any threshold too, but
gradually, and is not a band. Returns None when there is no such band: the caller
then falls back to another reference.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["MAX_COLUMNS", "InvertBand", "detect_invert", "invert_columns"]

MIN_CONTRAST = 0.15        # relative to the wall's median, like the defect detector
MIN_WIDTH_DEG = 20.0
MAX_WIDTH_DEG = 200.0
MIN_PERSISTENCE = 0.8      # share of columns in which the band shows
SMOOTH_DEG = 3.0
# Each edge of a band: the mean profile over EDGE_WINDOW_DEG just inside it against
# just outside it, each window SMOOTH_DEG clear of the edge (the smoothing's blur), must
# differ by EDGE_SHARE of the band's contrast. A sharp edge gives ~1; a cosine swell of
# any amplitude ~0.3 (its slope over the windows' 11 deg against its mean excess).
EDGE_WINDOW_DEG = 5.0
EDGE_SHARE = 0.5
# The band is a property of every column along the run: its statistics are taken over
# at most this many evenly spaced columns (a 4000-pair overview has ~10^4), so the
# working memory is bounded (~20 MB) however long the run is.
MAX_COLUMNS = 2048


@dataclass(frozen=True)
class InvertBand:
    """A detected band: centre (the invert), width, contrast and persistence."""

    theta_deg: float
    width_deg: float
    contrast: float
    persistence: float


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of every circular run of True, longest first."""
    if not mask.any():
        return []
    if mask.all():
        return [(0, mask.size)]
    shift = int(np.argmin(mask))            # a False row: runs do not wrap from here
    rolled = np.append(np.roll(mask, -shift), False)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], rolled.astype(np.int8)))))
    starts, ends = edges[0::2], edges[1::2]
    order = np.argsort(starts - ends, kind="stable")
    return [((int(starts[k]) + shift) % mask.size, int(ends[k] - starts[k])) for k in order]


def detect_invert(image: np.ndarray, deg_per_px: float) -> InvertBand | None:
    """The invert (centre of a persistent wide band) in mosaic theta, or None.

    Parameters
    ----------
    image : numpy.ndarray
        Mosaic (rows: theta, columns: z), float, NaN where not seen. Only
        :func:`invert_columns` of its columns are read.
    deg_per_px : float
        Degrees per row.
    """
    # Rows and columns without data give all-NaN medians (NaN is the right answer).
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return _detect(image, deg_per_px)


def invert_columns(n_cols: int) -> np.ndarray:
    """The columns :func:`detect_invert` reads of a mosaic ``n_cols`` wide.

    All of them, or ``MAX_COLUMNS`` evenly spaced ones (first and last included).
    """
    if n_cols <= MAX_COLUMNS:
        return np.arange(n_cols)
    return np.unique(np.linspace(0, n_cols - 1, MAX_COLUMNS).round().astype(np.intp))


def _detect(image: np.ndarray, deg_per_px: float) -> InvertBand | None:
    if image.shape[1] > MAX_COLUMNS:
        image = image[:, invert_columns(image.shape[1])]
    valid = np.isfinite(image)
    usable_cols = valid.mean(axis=0) >= 0.5
    if usable_cols.sum() < 5:
        return None
    img = image[:, usable_cols]
    col_median = _nanmedian(img, axis=0)
    norm = img / np.where(col_median > 0, col_median, np.nan)
    rows_ok = np.isfinite(norm).mean(axis=1) >= 0.5
    profile = np.full(image.shape[0], np.nan)
    profile[rows_ok] = _nanmedian(norm[rows_ok], axis=1)
    sigma = max(1.0, SMOOTH_DEG / deg_per_px)
    weight = ndimage.gaussian_filter1d(rows_ok.astype(float), sigma, mode="wrap")
    smooth = ndimage.gaussian_filter1d(np.nan_to_num(profile), sigma, mode="wrap")
    profile = np.where(rows_ok, smooth / np.maximum(weight, 1e-6), np.nan)
    dev = profile - np.nanmedian(profile)
    best = None
    for sign in (-1.0, 1.0):
        for start, length in _runs(np.nan_to_num(sign * dev) > MIN_CONTRAST):
            band = _band(norm, dev, sign, start, length, deg_per_px)
            if band is not None and (best is None or band.width_deg > best.width_deg):
                best = band
    return best


def _band(norm: np.ndarray, dev: np.ndarray, sign: float, start: int, length: int,
          deg_per_px: float) -> InvertBand | None:
    """The run of rows ``start`` .. ``start + length`` as a band, or None when it is not
    one (too narrow or wide, a gradual swell, not along the run)."""
    width = length * deg_per_px
    if not MIN_WIDTH_DEG <= width <= MAX_WIDTH_DEG:
        return None
    rows = (start + np.arange(length)) % dev.size
    contrast = float(np.nanmedian(dev[rows]))
    if min(_edge_steps(sign * dev, start, length, deg_per_px)) < EDGE_SHARE * abs(contrast):
        return None   # a gradual swell
    persistence = _persistence(norm, rows, sign)
    if persistence < MIN_PERSISTENCE:
        return None
    centre = (start + (length - 1) / 2) * deg_per_px % 360.0
    return InvertBand(centre, width, contrast, persistence)


def _edge_steps(excess: np.ndarray, start: int, length: int,
                deg_per_px: float) -> tuple[float, float]:
    """How much higher ``excess`` (the band's direction up) is just inside the band's
    first and last rows than just outside them (circular rows; NaN rows ignored)."""
    n = excess.size
    clear = int(np.ceil(SMOOTH_DEG / deg_per_px))
    window = np.arange(max(1, round(EDGE_WINDOW_DEG / deg_per_px)))
    first, last = start, start + length - 1

    def mean(rows: np.ndarray) -> float:
        values = excess[rows % n]
        values = values[np.isfinite(values)]
        return float(values.mean()) if values.size else np.nan

    steps = (mean(first + clear + window) - mean(first - clear - 1 - window),
             mean(last - clear - window) - mean(last + clear + 1 + window))
    return tuple(s if np.isfinite(s) else -np.inf for s in steps)  # type: ignore[return-value]


def _nanmedian(values: np.ndarray, axis: int) -> np.ndarray:
    """``np.nanmedian(values, axis=axis)`` of a 2-D array, the same values, from one sort
    (numpy's loops over the lines in Python when they hold NaN: ~4x slower here)."""
    lines = np.sort(values if axis == 1 else values.T, axis=1)   # NaN last
    if lines.shape[1] == 0:
        return np.full(len(lines), np.nan, values.dtype)
    n = np.count_nonzero(~np.isnan(lines), axis=1)   # infinities count, as numpy's
    rows = np.arange(len(lines))
    lo = lines[rows, np.maximum(n - 1, 0) // 2]
    hi = lines[rows, n // 2 - (n == 0)]
    # the mean of the two middle values, as np.median takes it (one for an odd count)
    return np.where(n > 0, np.where(n % 2 == 1, lo, (lo + hi) / 2), np.nan)


def _persistence(norm: np.ndarray, rows: np.ndarray, sign: float) -> float:
    """Share of columns where the band's median differs from the rest's by half the
    threshold in the band's direction."""
    inside = np.zeros(norm.shape[0], bool)
    inside[rows] = True
    band = _nanmedian(norm[inside], axis=0)
    rest = _nanmedian(norm[~inside], axis=0)
    ok = np.isfinite(band) & np.isfinite(rest)
    if not ok.any():
        return 0.0
    return float(np.mean(sign * (band[ok] - rest[ok]) > MIN_CONTRAST / 2))
