"""The lens' brightness fall-off, learned from the run as a function of image radius.

What an LED frame shows is albedo × LED irradiance (the physical model the unwrap
gives as each node's ``shading``) × the lens' vignetting × exposure. Vignetting
belongs to the lens: it falls off with the distance from the optical centre in the
image, whatever the probe's pose. A profile taken along the strip's axial columns
instead (the median over the circumference of each column) mixes image radii as soon
as the probe is off-centre or tilted: the wall on the near side is seen further from
the image centre than the far side at the same axial distance, so the near side comes
out too bright and the far side too dark, once per turn of the mosaic.

The fall-off is measured where two frames see the same wall (:func:`pair_ratios`): at
a node of their overlap the wall's albedo cancels in the ratio of the two values (each
divided by its shading), which leaves F(ρ in the second frame) / F(ρ in the first) times
the ratio of their exposures. Every overlap of the run gives such ratios at many pairs of
radii, and a least-squares solve for F over the rings gives the fall-off whatever the
wall shows (:meth:`RadialFlatField.from_pairs`); the exposure is taken as the same in
both frames of an overlap, and the overlaps across an exposure step are rejected as
outliers (:func:`_solve_pairs` says why it is not solved for).
A wall of two tones (a chart), on which any statistic of the values themselves follows
whichever tone fills a ring, is no harder than any other. Where too few overlaps were
measured, the median over frames of each ring's median value is the fall-off instead
(:func:`radial_levels`, :meth:`RadialFlatField.from_levels`): every frame sees another
piece of wall there, so the wall's own pattern averages out, less well.

Being a function of radius alone the fall-off cannot take up a feature of the wall that
stays at one clock position along the run (a water line, deposits along the invert),
which a two-dimensional flat field learned from a probe that does not roll would erase.
Clipped pixels carry only a lower bound of the light: they are left out of the ratios,
sort last in the medians, and are blended only where no frame saw the wall unclipped
(:func:`unclipped_weight`).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from pipestitch.mosaic._flat_field_kernels import (
    fall_off_at,
    group_medians,
    pair_cells,
    ring_index,
)

__all__ = ["CLIPPED_WEIGHT", "FIND", "RING_BINS", "FlatInput", "PairRatios", "RadialFlatField",
           "clipped_level", "flat_input", "optical_centre_px", "pair_ratios", "radial_edges",
           "radial_levels", "unclipped_weight"]

RING_BINS = 96          # rings of image radius: the fall-off is smooth over ~10 of them
MIN_RING_NODES = 20     # nodes a ring needs in one frame for a median
MIN_PAIR_NODES = 5      # node pairs a (ring, ring) cell of one overlap needs
MIN_PAIR_CELLS = 200    # cells over the run for the pairwise solve (else from_levels)
SMOOTHNESS = 1.0        # weight of the fall-off's second difference (per ring), against
                        # cells weighted by their standard error
REJECT_SIGMAS = 4.0     # cells further than this from the solve are left out (robust)
REJECT_ROUNDS = 3
CLIPPED_PLATEAU = 5e-4  # a frame is clipped where this fraction of its pixels or more
                        # sit at its maximum (a sensor's full scale, whatever the file's)
CLIPPED_WEIGHT = 1e-3   # a clipped node's blend weight, relative: used only where no
                        # frame saw that piece of wall unclipped


class _Camera(Protocol):
    width: int
    height: int

    def project(self, points: np.ndarray) -> np.ndarray: ...


def optical_centre_px(camera: _Camera) -> tuple[float, float]:
    """Pixel (col, row) where the optical axis meets the image."""
    col, row = camera.project(np.array([[0.0, 0.0, 1.0]]))[0]
    return float(col), float(row)


def radial_edges(camera: _Camera) -> np.ndarray:
    """Ring edges (px): ``RING_BINS`` equal rings from the optical centre to the image
    corner furthest from it."""
    col, row = optical_centre_px(camera)
    corners = np.array([[0, 0], [camera.width - 1, 0], [0, camera.height - 1],
                        [camera.width - 1, camera.height - 1]], float)
    reach = float(np.max(np.hypot(corners[:, 0] - col, corners[:, 1] - row)))
    return np.linspace(0.0, reach, RING_BINS + 1)


def radial_levels(flat: FlatInput, n_rings: int) -> np.ndarray:
    """Median of ``value / shading`` per ring of image radius for one strip (float32,
    NaN where a ring has fewer than ``MIN_RING_NODES`` nodes, or half of them clipped).

    Every 4th row and 2nd column of the strip is enough (the rings hold thousands of
    nodes). A clipped node's true ratio is only known to be higher: it sorts last, so
    the median stays exact while fewer than half of a ring's nodes are clipped.
    """
    sub = (slice(None, None, 4), slice(None, None, 2))
    ring, log_albedo = flat.ring[sub].ravel(), flat.log_albedo[sub].ravel()
    keep = (ring >= 0) & ~np.isnan(log_albedo)
    rings, counts, medians = group_medians(ring[keep].astype(np.int64), log_albedo[keep])
    levels = np.full(n_rings, np.nan, np.float32)
    enough = (counts >= MIN_RING_NODES) & (rings < n_rings)
    levels[rings[enough]] = np.exp(medians[enough])
    levels[~np.isfinite(levels)] = np.nan   # half the ring or more clipped: unknown
    return levels


@dataclass(frozen=True)
class RadialFlatField:
    """Brightness fall-off by image radius (median 1 over the rings the run saw).

    Attributes
    ----------
    centre : tuple of float
        Optical centre (col, row), px.
    radius_px : numpy.ndarray
        Ring centres (px).
    level : numpy.ndarray
        Relative brightness at each ring centre (rings no frame saw take the nearest
        seen ring's value).
    """

    centre: tuple[float, float]
    radius_px: np.ndarray
    level: np.ndarray

    @classmethod
    def from_levels(cls, levels: list[np.ndarray], edges: np.ndarray,
                    centre: tuple[float, float]) -> RadialFlatField:
        """The median over frames of their :func:`radial_levels`, normalised.

        Flat (1 everywhere) when no ring was seen by any frame.
        """
        mid = 0.5 * (edges[:-1] + edges[1:])
        stack = np.array(levels, np.float32).reshape(-1, len(mid))

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # rings no frame saw: NaN
            level = np.nanmedian(stack, axis=0) if len(stack) else np.full(len(mid), np.nan)
        seen = np.isfinite(level) & (level > 0)
        if not seen.any():
            return cls(centre, mid, np.ones(len(mid)))
        level = np.interp(mid, mid[seen], level[seen])
        return cls(centre, mid, level / np.median(level[seen]))

    @classmethod
    def from_pairs(cls, pairs: Sequence[PairRatios], edges: np.ndarray,
                   centre: tuple[float, float]) -> RadialFlatField | None:
        """Least squares over the overlaps' ratios (see the module docstring and
        :func:`_solve_pairs`): log F per ring, a smooth fall-off (second differences),
        outlying cells rejected. None when fewer than ``MIN_PAIR_CELLS`` cells were
        measured."""
        pairs = [p for p in pairs if len(p.count)]
        n_cells = sum(len(p.count) for p in pairs)
        if n_cells < MIN_PAIR_CELLS:
            return None
        mid = 0.5 * (edges[:-1] + edges[1:])
        log_f, seen = _solve_pairs(pairs, len(mid))
        level = np.exp(log_f - np.median(log_f[seen]))
        level = np.interp(mid, mid[seen], level[seen])   # rings no overlap saw: nearest
        return cls(centre, mid, level / np.median(level[seen]))

    def at(self, map_x: np.ndarray, map_y: np.ndarray, times: np.ndarray | None = None
           ) -> np.ndarray:
        """The fall-off at pixel positions (float32 maps; float32, same shape; linear
        between ring centres, the end rings' values beyond them); with ``times``
        (float32, same shape), ``times`` · the fall-off in float32, without the
        fall-off as an array of its own."""
        ring_px = float(self.radius_px[1] - self.radius_px[0])
        return fall_off_at(map_x, map_y, float(self.centre[0]), float(self.centre[1]),
                           ring_px, np.ascontiguousarray(self.level, np.float64),
                           np.empty((0, 0), np.float32) if times is None
                           else np.ascontiguousarray(times, np.float32))


class _Find:
    """The type of :data:`FIND`."""


FIND = _Find()   # a clipping level not given: found from the frame


def unclipped_weight(grey: np.ndarray, map_x: np.ndarray, map_y: np.ndarray,
                     weight: np.ndarray, level: float | _Find | None = FIND) -> np.ndarray:
    """``weight`` times ``CLIPPED_WEIGHT`` at the strip nodes whose interpolation reads
    a clipped pixel of the frame ``grey`` (their albedo is too low by an unknown amount:
    the wall there is taken from the frames that saw it unclipped, and from these only
    where none did). ``level``: the frame's :func:`clipped_level` when already known
    (None: known to be unclipped); by default (``FIND``) it is found here."""
    touched = _touches_clipped(grey, map_x, map_y, level)
    if touched is None:
        return weight
    return np.where(touched, weight * np.float32(CLIPPED_WEIGHT), weight).astype(np.float32)


def clipped_level(grey: np.ndarray) -> float | None:
    """The value at which the frame ``grey`` is clipped, or None when it is not.

    A pixel is clipped at the frame's maximum when that value is a plateau (at least
    ``CLIPPED_PLATEAU`` of the pixels): the full scale of the sensor, which for 12-bit
    data in 16-bit files is not the file's, and which a colour frame's grey reaches only
    where every channel clipped. A maximum held by a few pixels is light, not a limit.
    A frame unwrapped in several passes is looked at once (a full scan of the frame).
    """
    if not grey.size:
        return None
    top = cv2.minMaxLoc(grey)[1]
    if top <= 0 or cv2.countNonZero(cv2.compare(grey, top, cv2.CMP_GE)) < \
            CLIPPED_PLATEAU * grey.size:
        return None
    return float(top)


def _touches_clipped(grey: np.ndarray, map_x: np.ndarray, map_y: np.ndarray,
                     level: float | _Find | None = FIND) -> np.ndarray | None:
    """Nodes whose bilinear interpolation reads a clipped pixel (:func:`clipped_level`,
    found when not given); None when none is."""
    if isinstance(level, _Find):
        level = clipped_level(grey)
    if level is None:
        return None
    # 8-bit at 255: OpenCV's bilinear weights are multiples of 1/32, so any pixel the
    # interpolation reads (weight >= 1/64) gives a node at least 8.
    mask = cv2.compare(grey, level, cv2.CMP_GE)
    return cv2.remap(mask, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=0) > 0


def _ring_of(map_x: np.ndarray, map_y: np.ndarray, centre: tuple[float, float],
             edges: np.ndarray) -> np.ndarray:
    """Ring index of each pixel position (int16, -1 beyond the last); ``edges`` are equal
    rings from 0 (:func:`radial_edges`) about ``centre``. The radius is ``np.hypot`` of
    the float32 offsets, bitwise (C's ``hypotf`` computes in float64 and rounds once),
    in one compiled pass (:func:`~pipestitch.mosaic._flat_field_kernels.ring_index`)."""
    return ring_index(np.ascontiguousarray(map_x, np.float32),
                      np.ascontiguousarray(map_y, np.float32), float(np.float32(centre[0])),
                      float(np.float32(centre[1])),
                      float(np.float32((len(edges) - 1) / edges[-1])), len(edges) - 1)


@dataclass(frozen=True)
class FlatInput:
    """What one strip gives the flat field: ``log(value / shading)`` per node (NaN where
    the node has no data, +inf where it reads a clipped pixel: its true value is only
    known to be higher, -inf where it is black: only known to be lower) and its ring (-1
    outside the rings or without data)."""

    log_albedo: np.ndarray
    ring: np.ndarray


def flat_input(grey: np.ndarray, values: np.ndarray, shading: np.ndarray, weight: np.ndarray,
               map_x: np.ndarray, map_y: np.ndarray, centre: tuple[float, float],
               edges: np.ndarray, level: float | _Find | None = FIND) -> FlatInput:
    """The strip's :class:`FlatInput` (``grey``: the frame it was unwrapped from;
    ``level``: its :func:`clipped_level` when already known, None: known to be
    unclipped; by default (``FIND``) it is found here)."""
    ok = (weight > 0) & (shading > 0) & (values >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):   # black: -inf, sorts first
        log_albedo = np.log(values / shading, dtype=np.float32)
    log_albedo[~ok] = np.nan
    touched = _touches_clipped(grey, map_x, map_y, level)
    if touched is not None:
        log_albedo[touched & ok] = np.inf
    ring = _ring_of(map_x, map_y, centre, edges)
    ring[~ok] = -1
    return FlatInput(log_albedo, ring)


@dataclass(frozen=True)
class PairRatios:
    """One overlap's evidence: the two frames, and per (ring in the first frame, ring in
    the second) cell the median of log(second / first) and the number of node pairs."""

    frames: tuple[int, int]
    ring_first: np.ndarray
    ring_second: np.ndarray
    log_ratio: np.ndarray
    count: np.ndarray


def pair_ratios(first: FlatInput, second: FlatInput, motion_px: tuple[float, float],
                frames: tuple[int, int]) -> PairRatios:
    """Ratios of the same wall in two strips on one grid, the second moved by
    ``motion_px`` (rows, cols): second(n) ~ first(n + motion), rows wrapping around the
    pipe (:func:`pipestitch.mosaic.refine.patch_shifts`' convention). Every 4th row and
    2nd column of the second strip is paired with its nearest node in the first."""
    if first.ring.shape != second.ring.shape:
        raise ValueError(f"pair_ratios: strips of one grid expected, got {first.ring.shape} "
                         f"and {second.ring.shape}")
    n_bins = int(max(first.ring.max(initial=0), second.ring.max(initial=0))) + 1
    # clipped in both (inf - inf): left out
    cell, y = pair_cells(first.ring, first.log_albedo, second.ring, second.log_albedo,
                         round(motion_px[0]), round(motion_px[1]), n_bins)
    cells, counts, medians = group_medians(cell, y)
    enough = counts >= MIN_PAIR_NODES
    cells, counts = cells[enough], counts[enough]
    return PairRatios(frames, (cells // n_bins).astype(np.int16),
                      (cells % n_bins).astype(np.int16),
                      medians[enough].astype(np.float32), counts.astype(np.int32))


def _solve_pairs(pairs: Sequence[PairRatios], n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """log F per ring from the overlaps' cells, and which rings a cell measured.

    A cell's median has a standard error of ~1.25 σ / sqrt(count), σ the spread of one
    node pair's log ratio, measured on the residuals of each solve; the solve is
    repeated without the cells beyond ``REJECT_SIGMAS`` of their errors. The exposure
    is taken as the same in both frames of an overlap: one that changed between them
    (an auto-exposure step) offsets every cell of that overlap alike, and those cells
    are the ones rejected. Solving for an exposure per frame instead is not possible:
    on a probe moving steadily, a drift of the exposure along the run and a tilt of F
    change the overlaps' ratios in the same way.
    """
    first = np.concatenate([p.ring_first for p in pairs]).astype(np.int64)
    second = np.concatenate([p.ring_second for p in pairs]).astype(np.int64)
    y = np.concatenate([p.log_ratio for p in pairs]).astype(np.float64)
    root_n = np.sqrt(np.concatenate([p.count for p in pairs]).astype(np.float64)) / 1.25
    seen = np.zeros(n_bins, bool)
    seen[first] = seen[second] = True
    keep, sigma = np.ones(len(y), bool), 1.0
    for _ in range(REJECT_ROUNDS):
        log_f = _weighted_solve(first[keep], second[keep], y[keep], root_n[keep] / sigma,
                                n_bins)
        error = (y - (log_f[second] - log_f[first])) * root_n
        sigma = max(1.4826 * float(np.median(np.abs(error[keep]))), 1e-6)
        keep = np.abs(error) <= REJECT_SIGMAS * sigma
    return log_f, seen


def _weighted_solve(first: np.ndarray, second: np.ndarray, y: np.ndarray, w: np.ndarray,
                    n_bins: int) -> np.ndarray:
    """Least squares for log F per ring: w·(f[second] - f[first]) = w·y per cell and
    SMOOTHNESS·(f[k-1] - 2 f[k] + f[k+1]) = 0 per ring, by its normal equations (one
    unknown per ring: a small dense system; log F's constant, which no ratio sees, is
    held by a vanishing ridge)."""
    w2 = w * w
    normal = np.zeros((n_bins, n_bins))
    np.add.at(normal, (second, second), w2)
    np.add.at(normal, (first, first), w2)
    np.add.at(normal, (second, first), -w2)
    np.add.at(normal, (first, second), -w2)
    rhs = np.bincount(second, w2 * y, n_bins) - np.bincount(first, w2 * y, n_bins)
    curvature = np.diff(np.eye(n_bins), 2, axis=0) * SMOOTHNESS
    normal += curvature.T @ curvature + 1e-9 * np.trace(normal) / n_bins * np.eye(n_bins)
    return np.linalg.solve(normal, rhs)
