"""Defects on the unrolled wall: holes and spots, located and sized in millimetres.

On the mosaic (float albedo, NaN where not seen) the local background is a running
median over a window much larger than a defect (half the pipe's radius: a defect of
interest is a fraction of the pipe's size, whatever its size, so a defect does not
pull it), and the local contrast ``value / background - 1`` is thresholded relative to
its own robust noise (scikit-image labels and region properties do the rest):

* detection: |contrast| above 6 sigma, kept within [0.15, 0.8] (a busy texture
  such as corrosion has a large sigma, yet a hole must still count; a stain that is
  only ~50 % darker is then indistinguishable from the texture's own pits and is not
  reported; bright regions always need 6 sigma), regions of at least a disc of 3 %
  of the pipe's radius across (1 mm in a 65 mm pipe; and at least 5 mosaic pixels
  across on a coarse mosaic);
* sizing: each region is re-thresholded at half its own depth inside a box around it,
  so a blurred edge does not bias the size (the 50 % level of a symmetric blur sits
  on the true rim); a dark region that is not cut by unseen wall is then outlined
  along its rim, the steepest point of the step on rays from its centre
  (:mod:`pipestitch.measure.outline`), which does not move with the brightness of
  the wall beside it (corrosion, stains) as a fixed fraction of the depth does;
  equivalent diameter = that of a disc of the same area;
* kind: a **hole** is through the wall, so it returns (almost) no light: its interior
  (inside the rim by the blur measured there) returns at most 15 % of the light of
  the wall just outside its rim (90th percentile over the interior; simulated holes
  6-9 %, the darkest corrosion pits 23 % and more); anything else is a **spot**
  (stain, pit, deposit);
* a region that is the edge of a band along the pipe (standing water, a deposit along
  the invert), which the running median cannot follow, is not a defect: it is no
  darker or brighter than its own rows along the pipe, while the wall above and below
  it differ (:func:`_edge_of_a_band`);
* regions touching unseen wall are flagged ``partial`` (their size is a lower bound);
* for a defect across theta = 0/360, ``theta_min_deg`` > ``theta_max_deg`` (the range
  wraps).

Rows wrap around the pipe: the mosaic is rolled so that a row without detections is
at the top before labelling, so a defect across theta = 0/360 stays whole.

Clock positions (see docs/conventions.md): by default ("relative") 12 o'clock is the
image's up direction of the roll reference frame (theta = 270° in pipe coordinates),
3 o'clock theta = 0°, clockwise as seen looking in the direction of survey (theta
increasing); ``up_theta_deg`` moves 12 o'clock to the crown of a roll reference
(pipestitch.standards).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from skimage import measure

from pipestitch.geometry.clock import clock_hhmm
from pipestitch.geometry.wall_grid import WallGrid
from pipestitch.imaging import mad_sigma
from pipestitch.measure.outline import RimOutline, rim_outline

__all__ = ["Defect", "background_mm", "clock_position", "find_defects"]

# No constant below is in millimetres: intensities are fractions of the local wall or
# multiples of the mosaic's measured noise, lengths multiples of the pipe's measured
# radius or of the mosaic's pixel.
HOLE_LIGHT_FRACTION = 0.15  # a hole's interior returns at most this of its rim's light
MIN_CONTRAST = 0.15        # weaker regions are texture, not defects
NOISE_SIGMAS = 6.0
MAX_THRESHOLD = 0.8        # on a busy texture: still find what is 80 % off (holes)
BACKGROUND_RADII = 0.5     # running-median window (several defect diameters; 16 mm at 65)
MIN_DIAMETER_RADII = 0.03  # smallest defect reported (1 mm in a 65 mm pipe)
MIN_DIAMETER_PX = 5        # and never fewer mosaic pixels across (coarse mosaics)
EDGE_MARGIN_PX = 3         # nodes this close to unseen wall are not trusted


def background_mm(grid: WallGrid) -> float:
    """Width of the running-median background window on the wall of ``grid`` (mm)."""
    return BACKGROUND_RADII * grid.radius_mm


@dataclass(frozen=True)
class Defect:
    """A measured defect (mm, degrees; z and theta in the mosaic's coordinates)."""

    kind: str
    z_mm: float
    theta_deg: float
    clock: str
    diameter_mm: float
    area_mm2: float
    z_min_mm: float
    z_max_mm: float
    theta_min_deg: float
    theta_max_deg: float
    contrast: float
    confidence: float
    partial: bool


def clock_position(theta_deg: float, up_theta_deg: float = 270.0) -> str:
    """Clock position "H:MM" (to 5 minutes): 12 at ``up_theta_deg``, theta increasing clockwise."""
    return clock_hhmm(theta_deg, up_theta_deg)


def _background(image: np.ndarray, valid: np.ndarray, window_px: int) -> np.ndarray:
    """Running median of the seen wall (unseen nodes filled from their neighbourhood).

    Computed at an eighth of the resolution (a median over a window of several defect
    diameters does not need more) with rows wrapping around the pipe.
    """
    # Each eighth-size node: the mean of its 8 x 8 block, the block's unseen share taken
    # as the seen wall around it (a Gaussian of one node, 8 px: a fill at full size would
    # blur the whole image twice for the few blocks that need one).
    seen_sum = cv2.resize(np.where(valid, image, 0).astype(np.float32), None, fx=0.125,
                          fy=0.125, interpolation=cv2.INTER_AREA)
    seen = cv2.resize(valid.astype(np.float32), None, fx=0.125, fy=0.125,
                      interpolation=cv2.INTER_AREA)
    around = (cv2.GaussianBlur(seen_sum, (0, 0), 1)
              / np.maximum(cv2.GaussianBlur(seen, (0, 0), 1), 1e-6))
    small = seen_sum + (1 - seen) * around
    size = max(3, -(-window_px // 8) | 1)   # odd, and never narrower than asked
    pad = size // 2 + 1
    padded = np.pad(small, ((pad, pad), (pad, pad)), mode="wrap")
    padded[:, :pad] = padded[:, pad:pad + 1]
    padded[:, -pad:] = padded[:, -pad - 1:-pad]
    med = _median_filter(padded, size)[pad:-pad, pad:-pad]
    return cv2.resize(med, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_LINEAR)


def _median_filter(image: np.ndarray, size: int) -> np.ndarray:
    """``size`` x ``size`` running median (odd size) of a non-negative float image.

    ``cv2.medianBlur`` (constant time per pixel for 8-bit images; ~40x faster here than
    ``scipy.ndimage.median_filter``) on the image quantised to 256 levels of its
    maximum: a median commutes with that rounding, so the result is the exact median
    to within half a level (1/510 of the maximum; an 8-bit mosaic's own step). The
    border is replicated (the caller pads beforehand).
    """
    if size <= 5:    # float32 is supported as it is
        return cv2.medianBlur(np.ascontiguousarray(image, np.float32), size)
    top = float(np.max(image)) if image.size else 0.0
    if not top > 0:
        return np.zeros_like(image, dtype=np.float32)
    levels = np.rint(np.clip(image, 0, None) * (255.0 / top)).astype(np.uint8)
    return cv2.medianBlur(levels, size).astype(np.float32) * np.float32(top / 255.0)


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` with its holes filled, as ``scipy.ndimage.binary_fill_holes`` does (a
    hole: a 4-connected part of the background that does not reach the border), from
    OpenCV's connected components (~20x faster on a whole mosaic)."""
    n, labels = cv2.connectedComponents((~mask).astype(np.uint8), connectivity=4)
    outside = np.zeros(n, bool)
    for edge in (labels[0], labels[-1], labels[:, 0], labels[:, -1]):
        outside[edge] = True
    outside[0] = True          # label 0: the mask itself
    return mask | ~outside[labels]


def _roll_for_labelling(mask: np.ndarray) -> int:
    """Rows to roll by so that row 0 is the middle of the longest run of rows without
    detections (rows wrap), keeping every defect and its sizing box away from the cut;
    0 when every row has one."""
    empty = mask.sum(axis=1) == 0
    if not empty.any():
        return 0
    if empty.all():
        return 0
    start = int(np.argmin(empty))          # a non-empty row: runs do not wrap from here
    rolled = np.roll(empty, -start)
    best, best_len, run_start = 0, 0, None
    for k, e in enumerate(np.append(rolled, False)):
        if e and run_start is None:
            run_start = k
        elif not e and run_start is not None:
            if k - run_start > best_len:
                best, best_len = run_start, k - run_start
            run_start = None
    middle = (start + best + best_len // 2) % len(empty)
    return -middle


def _region_size(contrast: np.ndarray, box: tuple[slice, slice], depth: float,
                 seed: np.ndarray) -> np.ndarray:
    """Mask of the region at half its depth, grown from ``seed`` inside ``box``."""
    half = contrast[box] * np.sign(depth) > abs(depth) / 2
    labels = measure.label(half)
    keep = np.unique(labels[seed[box] & half])
    return np.isin(labels, keep[keep > 0])


def find_defects(image: np.ndarray, grid: WallGrid, *,
                 up_theta_deg: float = 270.0) -> list[Defect]:
    """Holes and spots on a mosaic (float, NaN where the wall was not seen).

    Parameters
    ----------
    image : numpy.ndarray, shape grid.shape
        Mosaic (rows: theta, columns: z), any positive intensity scale.
    grid : WallGrid
        Its grid, on the pipe's wall (``radius_mm``: the pipe radius).
    up_theta_deg : float
        Theta of 12 o'clock (default: the image's up direction of the reference frame).

    Returns
    -------
    list of Defect
        Sorted by z.

    Raises
    ------
    ValueError
        When ``image`` is not an image of ``grid``'s shape.
    """
    if np.shape(image) != grid.shape:
        raise ValueError(f"find_defects: mosaic of shape {np.shape(image)} on a grid of shape "
                         f"{grid.shape} (rows, columns)")
    valid = np.isfinite(image)
    if valid.sum() < 100:
        return []
    trusted = cv2.erode(valid.astype(np.uint8), np.ones((2 * EDGE_MARGIN_PX + 1,) * 2,
                                                       np.uint8)).astype(bool)
    window = round(background_mm(grid) / grid.mm_per_px_axial)
    background = _background(image, valid, window)
    # image / background - 1 where the wall was seen, 0 elsewhere (in place: a mosaic-sized
    # array fewer, and no pass to replace NaN first)
    contrast = np.divide(image, np.maximum(background, 1e-6))
    contrast -= 1
    contrast[~valid] = 0
    # The noise from every other row and column (a quarter of the nodes: the same
    # robust sigma to ~0.1 %, for a quarter of the time).
    values = contrast[::2, ::2][trusted[::2, ::2]]
    sigma = mad_sigma(values) if values.size else 0
    dark = float(np.clip(NOISE_SIGMAS * sigma, MIN_CONTRAST, MAX_THRESHOLD))
    bright = max(NOISE_SIGMAS * sigma, MIN_CONTRAST)
    mask = trusted & ((contrast < -dark) | (contrast > bright))
    pitch = max(grid.mm_per_px_axial, grid.mm_per_px_circ)
    min_diameter_mm = max(MIN_DIAMETER_RADII * grid.radius_mm, MIN_DIAMETER_PX * pitch)
    min_area = np.pi / 4 * min_diameter_mm**2 / (grid.mm_per_px_axial * grid.mm_per_px_circ)
    shift = _roll_for_labelling(mask)
    rolled = [np.roll(a, shift, axis=0) for a in (mask, contrast, valid, image)]
    labels = measure.label(_fill_holes(rolled[0]) & rolled[2])
    out = []
    for region in measure.regionprops(labels):
        if region.area < min_area or _edge_of_a_band(region, rolled[3], window,
                                                          (dark, bright)):
            continue
        out.append(_measure_region(region, rolled[1], rolled[2], labels, shift, grid,
                                   (dark, bright), up_theta_deg))
    return sorted(out, key=lambda d: d.z_mm)


def _edge_of_a_band(region: measure._regionprops.RegionProperties, image: np.ndarray,
                    window_px: int, thresholds: tuple[float, float]) -> bool:
    """Whether a region is the edge of a band that runs along the pipe (a water line,
    the edge of a deposit along the invert), not a defect.

    The running-median background cannot follow a step across the pipe: beside a band
    much darker (or brighter) than the wall it reads part of both, and stretches of the
    band's edge come out as "spots" along it. Such a region is not distinct from its
    own rows along the pipe (their median over ``window_px`` on each side, its own
    columns left out, is within the detection threshold of it: ``thresholds``, dark
    and bright), while the wall just above and just below it (strips as high as it,
    two pixels off) differ from each other by more than the weakest defect
    (``MIN_CONTRAST``): a step. A spot, a hole or a crack along the pipe is distinct
    from its own rows, or has the same wall on both sides.
    """
    r0, c0, r1, c1 = region.bbox
    cols = image.shape[1]
    span = np.arange(max(0, c0 - window_px), min(cols, c1 + window_px))
    beside = span[(span < c0) | (span >= c1)]
    height = max(3, r1 - r0)

    def level(first_row: int, columns: np.ndarray) -> float:
        rows = np.arange(first_row, first_row + height) % image.shape[0]   # around the pipe
        strip = image[np.ix_(rows, columns)]
        seen = strip[np.isfinite(strip)]
        return float(np.median(seen)) if seen.size else np.nan

    own = image[region.coords[:, 0], region.coords[:, 1]]
    own_level = float(np.median(own[np.isfinite(own)])) if np.isfinite(own).any() else np.nan
    along = level(r0, beside) if beside.size else np.nan
    above, below = level(r0 - 2 - height, span), level(r1 + 2, span)
    if not np.all(np.isfinite([own_level, along, above, below])) or max(above, below) <= 0:
        return False
    if abs(above - below) / max(above, below) <= MIN_CONTRAST:   # no step
        return False
    if along <= 0:   # rows that return no light: the region is theirs if it returns none
        return own_level <= 0
    threshold = thresholds[0] if own_level < along else thresholds[1]
    return abs(own_level / along - 1) < threshold


def _measure_region(region: measure._regionprops.RegionProperties, contrast: np.ndarray,
                    valid: np.ndarray, labels: np.ndarray, shift: int,
                    grid: WallGrid, thresholds: tuple[float, float],
                    up_theta_deg: float) -> Defect:
    r0, c0, r1, c1 = region.bbox
    pad = max(4, (r1 - r0) // 2)
    box = (slice(max(0, r0 - pad), min(contrast.shape[0], r1 + pad)),
           slice(max(0, c0 - pad), min(contrast.shape[1], c1 + pad)))
    seed = labels == region.label
    depth = float(np.median(contrast[seed]))
    sized = _region_size(contrast, box, depth, seed)
    if not sized.any():
        sized = seed[box]
    ring = cv2.dilate(sized.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    partial = bool(np.any(ring & ~valid[box]))
    rows, cols = np.nonzero(sized)
    rows, cols = rows + box[0].start, cols + box[1].start
    area_mm2 = rows.size * grid.mm_per_px_axial * grid.mm_per_px_circ
    centre = (rows.mean(), cols.mean())
    kind = "spot"
    if depth < 0:
        rim = None if partial else _rim(contrast, centre, area_mm2, grid)
        margin = EDGE_MARGIN_PX
        if rim is not None:
            rows, cols, area_mm2 = rim.rows, rim.cols, rim.area_mm2
            centre = (rim.centre_row, rim.centre_col)
            margin += int(np.ceil(2 * rim.blur_px))
        if _light_fraction(contrast, valid, rows, cols, margin) <= HOLE_LIGHT_FRACTION:
            kind = "hole"
    def theta_of(row: float) -> float:    # theta of a row of the rolled mosaic
        return float((grid.theta0_deg + (row - shift) * grid.deg_per_px) % 360.0)

    theta = theta_of(centre[0])
    # Confidence: how far past the detection threshold the region is (1 at 1.5 x).
    threshold = thresholds[0] if depth < 0 else thresholds[1]
    margin = abs(depth) / max(threshold, 1e-6) - 1
    return Defect(
        kind=kind, z_mm=float(grid.z0_mm + centre[1] * grid.mm_per_px_axial),
        theta_deg=theta, clock=clock_position(theta, up_theta_deg),
        diameter_mm=float(np.sqrt(4 * area_mm2 / np.pi)), area_mm2=float(area_mm2),
        z_min_mm=float(grid.z0_mm + cols.min() * grid.mm_per_px_axial),
        z_max_mm=float(grid.z0_mm + cols.max() * grid.mm_per_px_axial),
        theta_min_deg=theta_of(rows.min()), theta_max_deg=theta_of(rows.max()),
        contrast=depth,
        confidence=float(np.clip(margin / 0.5, 0.0, 1.0) * (0.5 if partial else 1)),
        partial=partial)


def _light_fraction(contrast: np.ndarray, valid: np.ndarray, rows: np.ndarray,
                    cols: np.ndarray, margin_px: int) -> float:
    """How much light a dark region's interior returns, as a fraction of the wall at its
    rim: the 90th percentile of its interior (``margin_px`` inside the outline given by
    ``rows``/``cols``: a polygon, or the region's own pixels) over the median of the
    seen wall in a band of the same width just outside it. 1 when either is empty."""
    m = 2 * margin_px + max(4, int(np.ptp(rows)) // 2)
    r0, c0 = int(np.floor(rows.min())) - m, int(np.floor(cols.min())) - m
    r1, c1 = int(np.ceil(rows.max())) + m + 1, int(np.ceil(cols.max())) + m + 1
    if r0 < 0 or c0 < 0 or r1 > contrast.shape[0] or c1 > contrast.shape[1]:
        lo = (max(r0, 0), max(c0, 0))
        r0, c0, r1, c1 = lo[0], lo[1], min(r1, contrast.shape[0]), min(c1, contrast.shape[1])
    mask = np.zeros((r1 - r0, c1 - c0), np.uint8)
    if np.allclose(rows, np.round(rows)) and np.allclose(cols, np.round(cols)):
        mask[rows.astype(int) - r0, cols.astype(int) - c0] = 1
    else:
        poly = np.stack([cols - c0, rows - r0], axis=1)
        cv2.fillPoly(mask, [np.round(poly * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)
    seen = valid[r0:r1, c0:c1]
    core = cv2.erode(mask, kernel).astype(bool) & seen
    near = cv2.dilate(mask, kernel)
    band = cv2.dilate(near, kernel).astype(bool) & ~near.astype(bool) & seen
    if not core.any() or not band.any():
        return 1.0
    level = 1.0 + contrast[r0:r1, c0:c1]
    wall = float(np.median(level[band]))
    return float(np.percentile(level[core], 90)) / wall if wall > 0 else 1.0


def _rim(contrast: np.ndarray, centre: tuple[float, float], area_mm2: float,
         grid: WallGrid) -> RimOutline | None:
    """The hole's rim (:mod:`pipestitch.measure.outline`) in ``contrast``'s pixels,
    searched in a box of twice the first radius guess around ``centre``."""
    radius_mm = float(np.sqrt(area_mm2 / np.pi))
    pitch = (grid.mm_per_px_circ, grid.mm_per_px_axial)
    half = [int(np.ceil(2 * radius_mm / p)) + 4 for p in pitch]
    lo = [max(0, int(c) - h) for c, h in zip(centre, half, strict=True)]
    hi = [min(n, int(c) + h + 1) for c, h, n in zip(centre, half, contrast.shape, strict=True)]
    crop = contrast[lo[0]:hi[0], lo[1]:hi[1]]
    rim = rim_outline(crop, (centre[0] - lo[0], centre[1] - lo[1]), radius_mm, pitch)
    if rim is None:
        return None
    return replace(rim, rows=rim.rows + lo[0], cols=rim.cols + lo[1],
                   centre_row=rim.centre_row + lo[0], centre_col=rim.centre_col + lo[1])
