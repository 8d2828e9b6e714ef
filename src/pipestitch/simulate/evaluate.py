"""Scoring a mosaic against the simulator's true wall (for tests and benchmarks).

The mosaic's theta and z are relative (roll and axial position are only known up to a
global offset), so the true wall is first brought onto the mosaic's grid with the
offsets that the true poses give, then refined by the median displacement of
textured patches, which is the "global axial offset and roll" every method is
allowed to get wrong. Then:

* SSIM (scikit-image) between the mosaic and the true albedo on the nodes the mosaic
  covers, after a least-squares gain and offset (the mosaic's brightness scale is
  arbitrary); and the same SSIM per tenth of the run (the covered columns in ten
  axial chunks), whose worst shows a stretch of the run the whole run's mean hides;
* local geometric error: the RMS displacement (mm) of 64 x 64 patches against the
  true wall, measured by phase correlation, after removing the median displacement.
  A patch of periodic texture (gratings, checkers) can lock onto the wrong period:
  patches further than max(0.5 mm, 5 robust sigma) from the median are counted as
  failed matches (``n_rejected``), not as geometry; for a warped baseline the robust
  sigma is large, so its real errors are kept;
* axial scale error: the slope of the patches' axial displacement against their z
  (mosaic z per true z, minus 1), which the local RMS hides: a mosaic 0.1 % short is
  0.33 mm off at the ends of a 330 mm run yet locally perfect; ``local_rms_mm`` is
  the RMS after removing that slope too;
* shading error: the mean absolute difference (in 8-bit levels of the true wall)
  between the mosaic, after the same gain and offset, and the truth, both low-passed
  to 4 mm (Gaussian sigma): the LED fall-off, vignetting and gain left in the mosaic.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from skimage.metrics import structural_similarity

from pipestitch.geometry import WallGrid
from pipestitch.mosaic.register import phase_shift

__all__ = ["MosaicScore", "WallImage", "score_mosaic", "truth_on_grid"]

PATCH_PX = 64
SSIM_CHUNKS = 10          # MosaicScore.ssim_tenths: the run in this many axial chunks
MIN_PATCH_RESPONSE = 0.1
MIN_PATCH_STD = 0.005     # flatter true-wall patches carry no position
SHADING_SIGMA_MM = 4.0


@dataclass(frozen=True, kw_only=True)
class WallImage:
    """A wall image on its grid (the true wall, or a mosaic: float, NaN = no data).

    Parameters
    ----------
    image : numpy.ndarray, shape grid.shape
        The image (rows: theta, columns: z).
    grid : WallGrid
        Its grid.

    Raises
    ------
    ValueError
        When ``image`` is not an image of ``grid``'s shape.
    """

    image: np.ndarray
    grid: WallGrid

    def __post_init__(self) -> None:
        if np.shape(self.image) != self.grid.shape:
            raise ValueError(f"WallImage: image of shape {np.shape(self.image)} on a grid of "
                             f"shape {self.grid.shape} (rows, columns)")


@dataclass(frozen=True)
class MosaicScore:
    """A mosaic's score against the true wall (see the module docstring).

    Attributes
    ----------
    ssim : float
        Mean SSIM over the covered nodes (NaN with too little data).
    geometric_rms_mm : float
        RMS displacement of the kept patches about their median (mm).
    n_patches, n_rejected : int
        Patches kept, and rejected as failed matches.
    coverage : float
        Fraction of the mosaic's nodes that have data.
    z_offset_mm, roll_offset_deg : float
        The offsets that took mosaic coordinates to true ones (after refinement).
    axial_scale_error : float
        Mosaic z per true z, minus 1.
    local_rms_mm : float
        RMS displacement after removing the axial scale and the offsets (mm).
    shading_dn : float
        Low-frequency brightness error (8-bit levels of the true wall).
    ssim_tenths : tuple of float
        Mean SSIM per tenth of the run: the columns with SSIM nodes, in
        ``SSIM_CHUNKS`` axial chunks of (nearly) equal width, left to right (NaN for
        a chunk without columns; empty with too little data).
    """

    ssim: float
    geometric_rms_mm: float
    n_patches: int
    n_rejected: int
    coverage: float
    z_offset_mm: float
    roll_offset_deg: float
    axial_scale_error: float = float("nan")
    local_rms_mm: float = float("nan")
    shading_dn: float = float("nan")
    ssim_tenths: tuple[float, ...] = ()

    @property
    def ssim_worst_tenth(self) -> float:
        """The lowest SSIM of the run's tenths (NaN without them)."""
        finite = [v for v in self.ssim_tenths if np.isfinite(v)]
        return float(min(finite)) if finite else float("nan")


def truth_on_grid(truth: WallImage, mosaic: WallImage, z_offset_mm: float,
                  roll_offset_deg: float) -> np.ndarray:
    """The true wall sampled at the mosaic's nodes (theta + roll offset, z + z offset).

    The truth is low-passed to the mosaic's pixel size first (Gaussian, sigma half a
    mosaic pixel), so fine texture the mosaic cannot hold does not alias. NaN outside
    the truth's axial extent.
    """
    m, t = mosaic.grid, truth.grid
    n_rows, n_cols = m.shape
    sig_r = 0.5 * m.deg_per_px / t.deg_per_px
    sig_c = 0.5 * m.mm_per_px_axial / t.mm_per_px_axial
    src = cv2.GaussianBlur(truth.image.astype(np.float32), (0, 0), sigmaX=max(sig_c, 0.1),
                           sigmaY=max(sig_r, 0.1), borderType=cv2.BORDER_REFLECT)
    theta, z = m.theta_z()
    theta = (theta + roll_offset_deg - t.theta0_deg) % 360.0
    z = z + z_offset_mm
    col = (z - t.z0_mm) / t.mm_per_px_axial
    row = theta / t.deg_per_px
    map_x = np.broadcast_to(col[None, :], (n_rows, n_cols)).astype(np.float32)
    map_y = np.broadcast_to(row[:, None], (n_rows, n_cols)).astype(np.float32)
    out = cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    out[:, (col < 0) | (col > truth.image.shape[1] - 1)] = np.nan
    return out


def _patch_displacements(mosaic: WallImage, reference: np.ndarray,
                         radius_mm: float) -> np.ndarray:
    """(N, 3) displacement (dz, d_arc) in mm (arcs on a wall of ``radius_mm``) of
    textured, fully covered patches, and the patch centre's mosaic z (mm)."""
    out = []
    win = cv2.createHanningWindow((PATCH_PX, PATCH_PX), cv2.CV_32F)
    g = mosaic.grid
    arc_mm = np.deg2rad(g.deg_per_px) * radius_mm
    n_rows, n_cols = mosaic.image.shape
    for r in range(0, n_rows - PATCH_PX + 1, PATCH_PX):
        for c in range(0, n_cols - PATCH_PX + 1, PATCH_PX):
            m = mosaic.image[r:r + PATCH_PX, c:c + PATCH_PX]
            t = reference[r:r + PATCH_PX, c:c + PATCH_PX]
            if not (np.isfinite(m).all() and np.isfinite(t).all()) or np.std(t) < MIN_PATCH_STD:
                continue
            dx, dy, resp = phase_shift(t.astype(np.float32), m.astype(np.float32), win)
            if resp >= MIN_PATCH_RESPONSE and max(abs(dx), abs(dy)) < PATCH_PX / 4:
                z = g.z0_mm + (c + PATCH_PX / 2) * g.mm_per_px_axial
                out.append((dx * g.mm_per_px_axial, dy * arc_mm, z))
    return np.array(out, float).reshape(-1, 3)


def score_mosaic(mosaic: WallImage, truth: WallImage, z_offset_mm: float,
                 roll_offset_deg: float) -> MosaicScore:
    """Score ``mosaic`` (float, NaN = no data) against the true wall.

    ``z_offset_mm`` and ``roll_offset_deg`` take mosaic coordinates to true ones (from
    the true poses); the median patch displacement refines them. Arcs are measured on
    the true wall (``truth.grid.radius_mm``).
    """
    radius_mm = truth.grid.radius_mm
    reference = truth_on_grid(truth, mosaic, z_offset_mm, roll_offset_deg)
    disp = _patch_displacements(mosaic, reference, radius_mm)
    if len(disp):
        dz, ds = np.median(disp[:, :2], axis=0)
        z_offset_mm -= dz
        roll_offset_deg -= np.rad2deg(ds / radius_mm)
        reference = truth_on_grid(truth, mosaic, z_offset_mm, roll_offset_deg)
        disp = _patch_displacements(mosaic, reference, radius_mm)
    rms, local, scale, n_rejected = float("nan"), float("nan"), float("nan"), 0
    if len(disp):
        dist = np.hypot(*(disp[:, :2] - np.median(disp[:, :2], axis=0)).T)
        robust_sigma = 1.4826 * float(np.median(dist))
        kept = dist <= max(0.5, 5 * robust_sigma)
        n_rejected = int(np.sum(~kept))
        rms = float(np.sqrt(np.mean(dist[kept] ** 2)))
        scale, local = _scale_and_local(disp[kept])
    coverage = float(np.mean(np.isfinite(mosaic.image)))
    fitted = _fitted(mosaic.image, reference)
    ssim, tenths = _ssim(fitted)
    return MosaicScore(ssim, rms, int(len(disp) - n_rejected),
                       n_rejected, coverage, z_offset_mm, roll_offset_deg, scale, local,
                       _shading_dn(fitted, mosaic.grid.mm_per_px_axial), tenths)


def _scale_and_local(disp: np.ndarray) -> tuple[float, float]:
    """Axial scale error (slope of dz against z) and the RMS displacement left after
    removing it and the median arc offset; NaN with too few patches or no z span."""
    z = disp[:, 2]
    if len(disp) < 3 or np.ptp(z) <= 0:
        return float("nan"), float("nan")
    slope, intercept = np.polyfit(z, disp[:, 0], 1)
    rest = np.column_stack([disp[:, 0] - (slope * z + intercept),
                            disp[:, 1] - np.median(disp[:, 1])])
    return float(slope), float(np.sqrt(np.mean(np.sum(rest**2, axis=1))))


def _fitted(mosaic: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mosaic after the least-squares gain and offset onto the reference, reference),
    both NaN where either has no data (all NaN with too little data)."""
    valid = np.isfinite(mosaic) & np.isfinite(reference)
    if valid.sum() < 1000:
        nan = np.full(mosaic.shape, np.nan, np.float32)
        return nan, nan
    a = np.vstack([mosaic[valid], np.ones(valid.sum())]).T
    gain, offset = np.linalg.lstsq(a, reference[valid], rcond=None)[0]
    return (np.where(valid, mosaic * gain + offset, np.nan).astype(np.float32),
            np.where(valid, reference, np.nan).astype(np.float32))


def _ssim(fitted: tuple[np.ndarray, np.ndarray]) -> tuple[float, tuple[float, ...]]:
    """Mean SSIM over the nodes 3 or more away from missing data, and its mean per
    axial chunk (``SSIM_CHUNKS`` of the columns holding such nodes); NaN and no chunks
    with too little data."""
    mosaic, reference = fitted
    valid = np.isfinite(mosaic)
    if valid.sum() < 1000:
        return float("nan"), ()
    a = np.where(valid, mosaic, 0).astype(np.float64)
    ref = np.where(valid, reference, 0).astype(np.float64)
    _, smap = structural_similarity(ref, a, data_range=1.0, full=True, win_size=7)
    inner = cv2.erode(valid.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    if not inner.any():
        return float("nan"), ()
    chunks = np.array_split(np.flatnonzero(inner.any(axis=0)), SSIM_CHUNKS)
    tenths = tuple(float(np.mean(smap[:, c][inner[:, c]])) if c.size else float("nan")
                   for c in chunks)
    return float(np.mean(smap[inner])), tenths


def _shading_dn(fitted: tuple[np.ndarray, np.ndarray], mm_per_px: float) -> float:
    """Mean |low-pass(mosaic) - low-pass(reference)| in 8-bit levels, over the nodes
    whose whole low-pass footprint has data."""
    mosaic, reference = fitted
    valid = np.isfinite(mosaic)
    if valid.sum() < 1000:
        return float("nan")
    sigma = SHADING_SIGMA_MM / mm_per_px
    weight = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), sigma)
    low = [cv2.GaussianBlur(np.where(valid, a, 0).astype(np.float32), (0, 0), sigma)
           / np.maximum(weight, 1e-6) for a in (mosaic, reference)]
    inner = weight > 0.99
    if not inner.any():
        return float("nan")
    return float(255 * np.mean(np.abs(low[0] - low[1])[inner]))
