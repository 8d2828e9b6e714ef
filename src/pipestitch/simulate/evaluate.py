"""Scoring a mosaic against the simulator's true wall (for tests and benchmarks).

The mosaic's theta and z are relative (roll and axial position are only known up to a
global offset), so the true wall is first brought onto the mosaic's grid with the
offsets that the true poses give, then refined by the median displacement of
textured patches, which is the "global axial offset and roll" every method is
allowed to get wrong. Then:

* SSIM (scikit-image) between the mosaic and the true albedo on the nodes the mosaic
  covers, after a least-squares gain and offset (the mosaic's brightness scale is
  arbitrary);
* local geometric error: the RMS displacement (mm) of 64 x 64 patches against the
  true wall, measured by phase correlation, after removing the median displacement.
  A patch of periodic texture (gratings, checkers) can lock onto the wrong period:
  patches further than max(0.5 mm, 5 robust sigma) from the median are counted as
  failed matches (``n_rejected``), not as geometry; for a warped baseline the robust
  sigma is large, so its real errors are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from skimage.metrics import structural_similarity

from pipestitch.mosaic.register import phase_shift

__all__ = ["MosaicScore", "WallImage", "score_mosaic", "truth_on_grid"]

PATCH_PX = 64
MIN_PATCH_RESPONSE = 0.1
MIN_PATCH_STD = 0.005     # flatter true-wall patches carry no position


@dataclass(frozen=True)
class WallImage:
    """A wall image in SPEC's convention: row i at theta0 + i·deg_per_px, col j at z0 + j·mm."""

    image: np.ndarray
    deg_per_px: float
    mm_per_px: float
    z0_mm: float


@dataclass(frozen=True)
class MosaicScore:
    """SSIM, geometric RMS (mm), patches used, and the offsets that aligned the mosaic."""

    ssim: float
    geometric_rms_mm: float
    n_patches: int
    n_rejected: int
    coverage: float
    z_offset_mm: float
    roll_offset_deg: float


def truth_on_grid(truth: WallImage, mosaic: WallImage, z_offset_mm: float,
                  roll_offset_deg: float) -> np.ndarray:
    """The true wall sampled at the mosaic's nodes (theta + roll offset, z + z offset).

    The truth is low-passed to the mosaic's pixel size first (Gaussian, sigma half a
    mosaic pixel), so fine texture the mosaic cannot hold does not alias. NaN outside
    the truth's axial extent.
    """
    n_rows, n_cols = mosaic.image.shape
    sig_r = 0.5 * mosaic.deg_per_px / truth.deg_per_px
    sig_c = 0.5 * mosaic.mm_per_px / truth.mm_per_px
    src = cv2.GaussianBlur(truth.image.astype(np.float32), (0, 0), sigmaX=max(sig_c, 0.1),
                           sigmaY=max(sig_r, 0.1), borderType=cv2.BORDER_REFLECT)
    theta = (np.arange(n_rows) * mosaic.deg_per_px + roll_offset_deg) % 360.0
    z = mosaic.z0_mm + np.arange(n_cols) * mosaic.mm_per_px + z_offset_mm
    col = (z - truth.z0_mm) / truth.mm_per_px
    row = theta / truth.deg_per_px
    map_x = np.broadcast_to(col[None, :], (n_rows, n_cols)).astype(np.float32)
    map_y = np.broadcast_to(row[:, None], (n_rows, n_cols)).astype(np.float32)
    out = cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    out[:, (col < 0) | (col > truth.image.shape[1] - 1)] = np.nan
    return out


def _patch_displacements(mosaic: WallImage, reference: np.ndarray,
                         radius_mm: float) -> np.ndarray:
    """(N, 2) displacement (dz, d_arc) in mm of textured, fully covered patches."""
    out = []
    win = cv2.createHanningWindow((PATCH_PX, PATCH_PX), cv2.CV_32F)
    arc_mm = np.deg2rad(mosaic.deg_per_px) * radius_mm
    n_rows, n_cols = mosaic.image.shape
    for r in range(0, n_rows - PATCH_PX + 1, PATCH_PX):
        for c in range(0, n_cols - PATCH_PX + 1, PATCH_PX):
            m = mosaic.image[r:r + PATCH_PX, c:c + PATCH_PX]
            t = reference[r:r + PATCH_PX, c:c + PATCH_PX]
            if not (np.isfinite(m).all() and np.isfinite(t).all()) or np.std(t) < MIN_PATCH_STD:
                continue
            dx, dy, resp = phase_shift(t.astype(np.float32), m.astype(np.float32), win)
            if resp >= MIN_PATCH_RESPONSE and max(abs(dx), abs(dy)) < PATCH_PX / 4:
                out.append((dx * mosaic.mm_per_px, dy * arc_mm))
    return np.array(out, float).reshape(-1, 2)


def _ssim(mosaic: np.ndarray, reference: np.ndarray) -> float:
    valid = np.isfinite(mosaic) & np.isfinite(reference)
    if valid.sum() < 1000:
        return float("nan")
    a = np.vstack([mosaic[valid], np.ones(valid.sum())]).T
    gain, offset = np.linalg.lstsq(a, reference[valid], rcond=None)[0]
    fitted = np.where(valid, mosaic * gain + offset, 0).astype(np.float64)
    ref = np.where(valid, reference, 0).astype(np.float64)
    _, smap = structural_similarity(ref, fitted, data_range=1.0, full=True, win_size=7)
    inner = cv2.erode(valid.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    return float(np.mean(smap[inner]))


def score_mosaic(mosaic: WallImage, truth: WallImage, radius_mm: float, z_offset_mm: float,
                 roll_offset_deg: float) -> MosaicScore:
    """Score ``mosaic`` (float, NaN = no data) against the true wall.

    ``z_offset_mm`` and ``roll_offset_deg`` take mosaic coordinates to true ones (from
    the true poses); the median patch displacement refines them.
    """
    reference = truth_on_grid(truth, mosaic, z_offset_mm, roll_offset_deg)
    disp = _patch_displacements(mosaic, reference, radius_mm)
    if len(disp):
        dz, ds = np.median(disp, axis=0)
        z_offset_mm -= dz
        roll_offset_deg -= np.rad2deg(ds / radius_mm)
        reference = truth_on_grid(truth, mosaic, z_offset_mm, roll_offset_deg)
        disp = _patch_displacements(mosaic, reference, radius_mm)
    rms, n_rejected = float("nan"), 0
    if len(disp):
        dist = np.hypot(*(disp - np.median(disp, axis=0)).T)
        robust_sigma = 1.4826 * float(np.median(dist))
        kept = dist <= max(0.5, 5 * robust_sigma)
        n_rejected = int(np.sum(~kept))
        rms = float(np.sqrt(np.mean(dist[kept] ** 2)))
    coverage = float(np.mean(np.isfinite(mosaic.image)))
    return MosaicScore(_ssim(mosaic.image, reference), rms, int(len(disp) - n_rejected),
                       n_rejected, coverage, z_offset_mm, roll_offset_deg)
