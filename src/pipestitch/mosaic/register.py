"""Registration: axial shift and roll between unwrapped strips, and a global solve.

Two strips of the same grid (each in its own frame's (theta, z)) show the same wall
up to the probe's advance dz and roll d(gamma) between the frames:
``strip_j(theta, z) = strip_i(theta + d_gamma, z + dz)``. The shift is measured by
sub-pixel phase correlation (``cv2.phaseCorrelate``) of the strips' local contrast,
weighted by their quality and tapered along z only, so the correlation is circular
in theta as the pipe is. Every frame is linked to the next one and the one after, and
the positions of the whole run are then solved at once by robust least squares over
all links and the odometer (a soft-L1 loss, by reweighted sparse solves), so a bad link
or an odometer slip is outvoted instead of being chained into every later frame. The
odometer's noise is measured on the run (:func:`odometer_noise_mm`), not assumed.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, identity, lil_matrix
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve

from pipestitch.geometry import WallGrid
from pipestitch.imaging import mad_sigma, median
from pipestitch.mosaic._register_kernels import (
    cross_power_ccs,
    gradient_moments,
    minus_weighted_mean,
    polish,
    tapered_image,
    weighted_peak,
)
from pipestitch.mosaic.noise import PatchNoise
from pipestitch.mosaic.unwrap import Strip, local_contrast

__all__ = [
    "Link",
    "MotionPrior",
    "Positions",
    "measure_overlap_shift",
    "measure_shift",
    "odometer_noise_mm",
    "phase_shift",
    "polish_moments",
    "predict_motion",
    "registration_image",
    "shared_taper",
    "solve_positions",
    "spectrum",
    "strip_contrast",
]

MIN_RESPONSE = 0.04     # phase-correlation peaks below this are not trusted at all
# A patch's noise is subtracted where at least this share of its gradient energy is
# texture: three standard deviations of a noise-only patch's energy (3.4 % for white
# noise under the 64 x 64 Hanning window, measured), so the corrected Hessian is never a
# noise fluctuation about zero. Brushed aluminium at 1224 x 1024: 15-30 % texture.
MIN_SIGNAL_SHARE = 0.1
PRIOR_FLOOR = 0.1       # weight of the motion prior far from the expected motion


@dataclass(frozen=True, slots=True)
class Link:
    """Measured motion from frame ``i`` to frame ``j``: z_j - z_i and roll_j - roll_i."""

    i: int
    j: int
    dz_mm: float
    droll_deg: float
    response: float
    dz_sigma_mm: float
    droll_sigma_deg: float


def _sigma_px(response: float) -> float:
    """Nominal 1-sigma of a phase-correlation shift in pixels: 0.1 px for a perfect peak,
    growing as the peak weakens (less common texture)."""
    return 0.1 / max(response, MIN_RESPONSE) ** 0.5

def phase_shift(first: np.ndarray, second: np.ndarray, window: np.ndarray | None = None, *,
                iterations: int = 3, noise: PatchNoise | None = None
                ) -> tuple[float, float, float]:
    """Sub-pixel shift d with ``second(x) = first(x - d)``: (dx, dy, peak response).

    ``cv2.phaseCorrelate`` finds the peak robustly, even for large shifts, but its
    sub-pixel step (a 5 x 5 weighted centroid) is biased by up to ~0.3 px for
    fractional shifts (measured on smooth textures; exact at whole pixels). So the
    shift is then polished by Gauss-Newton on the images themselves (Lucas-Kanade
    for a translation: ``second`` moved back by the estimate, cubic interpolation,
    wrapping, and the residual solved from the image gradients). That removes the
    centroid's bias but not the interpolation's: OpenCV's cubic kernel (a = -0.75,
    read by ``shifted_residual_moments``) leaves up to ~0.04 px on fine textures (measured on
    periodic Gaussian-filtered noise, sigma 1-2 px, at quarter-pixel shifts; Lanczos-4
    leaves ~0.005 px plus the 1/64 px quantisation, at ~4x the cost). Hand-written
    because neither library option fits: the upsampled-DFT estimator of scikit-image
    is accurate but ~10x slower per patch, and ``cv2.findTransformECC`` drifted on
    small windowed patches in our tests.

    ``noise``: what the noise of ``first`` adds to the polish's sums
    (:func:`pipestitch.mosaic.noise.patch_noise`), subtracted.
    """
    # The mean carries no position and, under a window, pulls the estimate towards 0.
    first, second = _minus_weighted_mean(first, window), _minus_weighted_mean(second, window)
    (dx, dy), response = cv2.phaseCorrelate(first, second, window)
    dx, dy = _polish(first, second, window, dx, dy, iterations, noise)
    return dx, dy, float(response)


def _minus_weighted_mean(image: np.ndarray, weight: np.ndarray | None) -> np.ndarray:
    """``image`` less its mean weighted by ``weight`` (None: the plain mean), float32."""
    if weight is None:
        image = np.ascontiguousarray(image, np.float32)
        return image - np.float32(image.mean(dtype=np.float64))
    out = np.array(image, np.float32, order="C")
    minus_weighted_mean(out, np.ascontiguousarray(weight, np.float32).ravel(),
                        weight_total(weight))
    return out


def weight_total(weight: np.ndarray) -> float:
    """The sum of a weighting window as :func:`phase_shift` divides by (float64)."""
    return max(float(np.asarray(weight, np.float32).sum(dtype=np.float64)), 1e-12)


def _polish(first: np.ndarray, second: np.ndarray, weight: np.ndarray | None, dx: float,
            dy: float, iterations: int, noise: PatchNoise | None = None,
            moments: tuple[float, float, float] | None = None) -> tuple[float, float]:
    """Lucas-Kanade steps on a translation d with ``second(x) = first(x - d)``
    (:func:`~pipestitch.mosaic._register_kernels.polish`).

    ``weight`` None weighs every pixel 1. ``noise``: the expected share of ``first``'s
    noise in the residual moments and in the Hessian's diagonal, subtracted from both
    (:mod:`pipestitch.mosaic.noise`); not where it would leave less than
    ``MIN_SIGNAL_SHARE`` of the Hessian (a patch of noise alone). ``moments``:
    ``first``'s gradient moments under ``weight`` when already computed
    (:func:`polish_moments`).
    """
    if not (np.isfinite(dx) and np.isfinite(dy)):
        return float(dx), float(dy)
    first = np.ascontiguousarray(first, np.float32)
    second = np.ascontiguousarray(second, np.float32)
    weight = (np.zeros((0, 0), np.float32) if weight is None
              else np.ascontiguousarray(weight, np.float32))
    a11, a12, a22 = gradient_moments(first, weight) if moments is None else moments
    sums = (np.empty(0) if noise is None
            else np.array([noise.d_x, noise.d_y, noise.h_x, noise.h_y], float))
    dx, dy = polish(first, second, weight, float(dx), float(dy), iterations, sums,
                    float(a11), float(a12), float(a22), MIN_SIGNAL_SHARE)
    return float(dx), float(dy)


@dataclass(frozen=True)
class MotionPrior:
    """Expected motion from frame i to frame j and its 1-sigma slack (mm, degrees)."""

    dz_mm: float
    droll_deg: float
    dz_sigma_mm: float
    droll_sigma_deg: float


def predict_motion(i: int, j: int, links: Sequence[Link],
                   odometry_mm: Mapping[int, float] | None = None) -> MotionPrior:
    """What the probe most likely did between frames i and j, from the run so far.

    The odometer when it has both frames (slack 3 mm + 20 %: it slips); otherwise k
    times the median of the last consecutive steps found (slack max(3 mm, k·step/2));
    with neither, z is free. Roll: k times the recent roll rate, slack 5° per frame.
    A wall with a periodic pattern (a row of equally spaced holes, a chart) correlates
    almost as well one period off: the prior keeps registration on the probe's
    plausible motion.
    """
    k = j - i
    steps = _last_steps(links, 5)
    rate_roll = float(median(np.array([ln.droll_deg for ln in steps], float))) if steps else 0.0
    roll = (k * rate_roll, 5.0 * abs(k))
    if odometry_mm and i in odometry_mm and j in odometry_mm:
        dz = odometry_mm[j] - odometry_mm[i]
        return MotionPrior(dz, roll[0], 3.0 + 0.2 * abs(dz), roll[1])
    if steps:
        step = float(median(np.array([ln.dz_mm for ln in steps], float)))
        return MotionPrior(k * step, roll[0], max(3.0, abs(k * step) / 2), roll[1])
    return MotionPrior(0.0, roll[0], np.inf, roll[1])


def _last_steps(links: Sequence[Link], count: int) -> list[Link]:
    """The last ``count`` links between consecutive frames, in order; read from the end
    (a long run holds thousands of links: a scan of all of them per frame is O(N²))."""
    found: list[Link] = []
    for ln in reversed(links):
        if ln.j - ln.i == 1:
            found.append(ln)
            if len(found) == count:
                break
    return found[::-1]


def spectrum(image: np.ndarray) -> np.ndarray:
    """The DFT :func:`measure_shift` correlates, for reuse (float32 ``image``).

    Packed (CCS, ``cv2.dft`` of a real image): half the work and memory of the
    complex form, which the correlation does not need.
    """
    return cv2.dft(image)


def polish_moments(image: np.ndarray) -> tuple[float, float, float]:
    """The gradient moments :func:`measure_shift` polishes a shift from ``image`` with,
    for reuse (float32 ``image``): a registration image is the first image of several
    links."""
    return gradient_moments(np.ascontiguousarray(image, np.float32), np.zeros((0, 0), np.float32))


def _prior_peak(first: np.ndarray, second: np.ndarray, expected_px: tuple[float, float],
                sigma_px: tuple[float, float],
                spectra: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, float, float]:
    """Phase-correlation peak weighted by a Gaussian prior on the shift (whole pixels).

    Returns (dx, dy, response) with ``second(x) = first(x - d)``; rows are circular.
    The response is the correlation surface summed over the 5 x 5 pixels around the
    peak, as ``cv2.phaseCorrelate`` reports it.
    """
    fa, fb = spectra if spectra is not None else (spectrum(first), spectrum(second))
    surface = cv2.idft(cross_power_ccs(fb, fa), flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    n_rows, n_cols = surface.shape
    sy = (np.arange(n_rows) + n_rows // 2) % n_rows - n_rows // 2
    sx = (np.arange(n_cols) + n_cols // 2) % n_cols - n_cols // 2
    wy = (sy - expected_px[1] + n_rows / 2) % n_rows - n_rows / 2
    # The Gaussian is separable: two 1-D profiles (float32), multiplied in the kernel.
    g_rows = np.exp(-0.5 * (wy / sigma_px[1]) ** 2).astype(np.float32)
    g_cols = np.exp(-0.5 * ((sx - expected_px[0]) / sigma_px[0]) ** 2).astype(np.float32)
    # The floor lets a clearly stronger peak far from the prior win (an odometer that
    # slipped by more than its slack) while a comparable one (one period off) does not.
    row, col = weighted_peak(surface, g_rows, g_cols, PRIOR_FLOOR)
    near = surface[np.ix_((row + np.arange(-2, 3)) % n_rows, (col + np.arange(-2, 3)) % n_cols)]
    return float(sx[col]), float(sy[row]), float(np.sum(near))


def strip_contrast(strip: Strip, *, sigma_px: float = 6.0) -> np.ndarray:
    """Local contrast of a strip (value / local mean - 1; 0 where masked), float32."""
    contrast, _ = local_contrast(strip.values, sigma_px)
    return contrast


def registration_image(contrast: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Quality-weighted local contrast, tapered to 0 at both z ends (float32)."""
    taper = np.hanning(contrast.shape[1] + 2)[1:-1].astype(np.float32)
    return tapered_image(np.ascontiguousarray(contrast, np.float32),
                         np.ascontiguousarray(weight, np.float32), taper)


def shared_taper(n_cols: int, shift_px: float) -> float:
    """Share of the :func:`registration_image` taper's energy that two strips ``n_cols``
    wide, ``shift_px`` apart along z, have in common: sum h(x) h(x - s) / sum h(x)^2
    (1 at no shift, 0 from a whole strip's width on)."""
    taper = np.hanning(n_cols + 2)[1:-1]
    s = int(round(abs(shift_px)))
    if s >= n_cols:
        return 0.0
    return float(np.dot(taper[s:], taper[:n_cols - s]) / np.dot(taper, taper))


def measure_overlap_shift(first: np.ndarray, first_weight: np.ndarray, second: np.ndarray,
                          second_weight: np.ndarray, grid: WallGrid, i: int, j: int,
                          prior: MotionPrior) -> Link | None:
    """:func:`measure_shift` of two strips' local contrasts (``first``, ``second``, with
    their quality weights) on the part of the wall the ``prior`` says they share: each
    cut to it and tapered over it alone. For a large step, where the whole strips'
    tapers leave the common wall only their faint ends. None when the prior expects no
    common part of at least a quarter of a strip."""
    link = _cut_shift(first, first_weight, second, second_weight, grid, i, j, prior)
    if link is None or abs(link.dz_mm - prior.dz_mm) < grid.mm_per_px_axial:
        return link
    # cut again where the measured step puts the common wall (the prior may be mm off),
    # so that the Lucas-Kanade polish starts within a pixel
    again = MotionPrior(link.dz_mm, link.droll_deg, prior.dz_sigma_mm, prior.droll_sigma_deg)
    return _cut_shift(first, first_weight, second, second_weight, grid, i, j, again) or link


def _cut_shift(first: np.ndarray, first_weight: np.ndarray, second: np.ndarray,
               second_weight: np.ndarray, grid: WallGrid, i: int, j: int,
               prior: MotionPrior) -> Link | None:
    """:func:`measure_overlap_shift`'s one measurement, cut where ``prior`` says."""
    n_cols = first.shape[1]
    s = int(round(prior.dz_mm / grid.mm_per_px_axial))
    width = n_cols - abs(s)
    if width < n_cols // 4:
        return None
    a, b = (slice(s, n_cols), slice(0, width)) if s >= 0 else (slice(0, width),
                                                                 slice(-s, n_cols))
    cut = MotionPrior(prior.dz_mm - s * grid.mm_per_px_axial, prior.droll_deg,
                      prior.dz_sigma_mm, prior.droll_sigma_deg)
    link = measure_shift(registration_image(first[:, a], first_weight[:, a]),
                         registration_image(second[:, b], second_weight[:, b]), grid, i, j, cut)
    if link is None:
        return None
    return Link(i, j, link.dz_mm + s * grid.mm_per_px_axial, link.droll_deg, link.response,
                link.dz_sigma_mm, link.droll_sigma_deg)


def _any_nonzero(image: np.ndarray) -> bool:
    """``numpy.any(image)``: for a 2-D image ``cv2.hasNonZero``, which stops at the first
    non-zero value (numpy reads the whole image: ~0.1-0.2 ms a registration image, twice
    for each of a frame's several links)."""
    if image.ndim == 2:
        return bool(cv2.hasNonZero(image))
    return bool(np.any(image))


def measure_shift(first: np.ndarray, second: np.ndarray, grid: WallGrid, i: int,
                  j: int, prior: MotionPrior | None = None,
                  spectra: tuple[np.ndarray, np.ndarray] | None = None,
                  first_moments: tuple[float, float, float] | None = None) -> Link | None:
    """Link from frame i to frame j by phase correlation of their registration images.

    With a ``prior`` the correlation peak is sought near the expected motion
    (:func:`predict_motion`). ``spectra``: the images' :func:`spectrum`, and
    ``first_moments`` the first's :func:`polish_moments`, when already computed (each
    frame is correlated with several). Returns None when the peak is below
    ``MIN_RESPONSE`` (no common texture).
    """
    if not (_any_nonzero(first) and _any_nonzero(second)):
        return None
    if prior is None or not (np.isfinite(prior.dz_sigma_mm) or np.isfinite(prior.droll_sigma_deg)):
        dx, dy, response = phase_shift(first, second, iterations=0)
    else:
        # Motion m and correlation shift d are opposite: strip_j(x) = strip_i(x + m).
        expected = (-prior.dz_mm / grid.mm_per_px_axial, -prior.droll_deg / grid.deg_per_px)
        sigma = (prior.dz_sigma_mm / grid.mm_per_px_axial, prior.droll_sigma_deg / grid.deg_per_px)
        dx, dy, response = _prior_peak(first, second, expected, sigma, spectra)
    # One polishing step: ~0.03 px, and the refinement replaces most links anyway.
    dx, dy = _polish(first, second, None, dx, dy, 1, moments=first_moments)
    if not np.isfinite(response) or response < MIN_RESPONSE:
        return None
    # phaseCorrelate: second(x) = first(x - d), and strip_j(x) = strip_i(x + motion).
    sigma = _sigma_px(response)
    return Link(i, j, -dx * grid.mm_per_px_axial, -dy * grid.deg_per_px, float(response),
                sigma * grid.mm_per_px_axial, sigma * grid.deg_per_px)


@dataclass(frozen=True)
class Positions:
    """Solved axial position and roll of every frame (NaN where unconstrained).

    Attributes
    ----------
    z_mm, roll_deg : numpy.ndarray
        Per frame; z is anchored to the odometer (median offset 0) when there is one,
        else to the first placed frame at 0; roll to 0 at the first frame of the
        largest group of frames linked by registration.
    odometer_scale : float
        Fitted scale of the odometer (1 without one).
    outliers : list
        ``(i, j, source)`` of measurements the robust solve rejected (beyond 3 sigma).
    roll_guessed : list
        Placed frames not linked to the roll reference by registration (only by the
        odometer): their roll is interpolated, not measured.
    roll_reference : str
        "relative" (as above), or "imu" once the roll has been offset to an IMU's.
    odometer_sigma_mm : float
        The odometer's 1-sigma per increment the solve used (given or measured;
        NaN without an odometer).
    """

    z_mm: np.ndarray
    roll_deg: np.ndarray
    odometer_scale: float
    outliers: list[tuple[int, int, str]]
    roll_guessed: list[int] = field(default_factory=list)
    roll_reference: str = "relative"
    odometer_sigma_mm: float = float("nan")


def _components(n: int, edges: Sequence[tuple[int, int]]) -> np.ndarray:
    """Connected-component label of every node (``scipy.sparse.csgraph``)."""
    ij = np.array(edges, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(ij)), (ij[:, 0], ij[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels


def _robust_linear(rows: list[tuple[int, int, float, float]], n: int, n_extra: int = 0,
                   extra: Sequence[tuple[int, float, float]] = ()) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Solve (x_j - x_i - value) / sigma = 0 robustly; returns x and the rows kept.

    ``rows`` are (i, j, value, sigma), i = -1 for a prior on x_j alone; ``extra`` are
    (row index, coefficient, unused) that make that row (x_j - x_i - coefficient·x[n]) /
    sigma: the odometer increment times the scale unknown x[n].
    """
    m = len(rows)
    a = lil_matrix((m, n + n_extra))
    b = np.zeros(m)
    for k, (i, j, value, sigma) in enumerate(rows):
        if i >= 0:
            a[k, i] = -1 / sigma
        a[k, j] = 1 / sigma
        b[k] = value / sigma
    for k, coef, _ in extra:
        a[k, n] = -coef / rows[k][3]
        b[k] = 0.0
    a = a.tocsr()
    # A bounded-influence fit finds the outliers; rejecting them (beyond 3 sigma) and
    # solving again by plain least squares removes the pull they keep under soft-L1.
    x = _soft_l1_solve(a, b, f_scale=2.0)
    keep = np.abs(a @ x - b) <= 3.0
    keep[[k for k, row in enumerate(rows) if row[0] < 0]] = True   # priors and gauge stay
    return _weighted_solve(a[keep], b[keep]), keep


def _weighted_solve(a: csr_matrix, b: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Sparse weighted least squares by a direct solve of the normal equations.

    A ridge of 1e-12 of the largest diagonal fixes the level of components no row ties
    to the rest (the caller places them, or not, per component). Hand-written because
    the iterative solver of scipy's ``least_squares`` for sparse problems (LSMR) stops
    far from the solution on long chains of frames (1000s of links whose positions are
    fixed only through the whole chain): a 250-pair run lost 353 of 497 links to it.
    """
    at = a.T.multiply(w).tocsr() if w is not None else a.T.tocsr()
    normal = (at @ a).tocsc()
    ridge = 1e-12 * max(float(normal.diagonal().max()), 1e-300)
    return spsolve(normal + ridge * identity(normal.shape[0], format="csc"), at @ b)


def _soft_l1_solve(a: csr_matrix, b: np.ndarray, f_scale: float,
                   iterations: int = 50) -> np.ndarray:
    """Minimise sum rho((a x - b) / f_scale) for scipy's soft-L1 rho, by iteratively
    reweighted least squares (rho is convex: IRLS from the plain solution converges to
    its minimum; weight rho'(z) = 1 / sqrt(1 + z), z = (r / f_scale)**2)."""
    x = _weighted_solve(a, b)
    for _ in range(iterations):
        r = a @ x - b
        new = _weighted_solve(a, b, 1.0 / np.sqrt(1.0 + (r / f_scale) ** 2))
        if np.max(np.abs(new - x)) < 1e-9 * max(1.0, float(np.max(np.abs(new)))):
            return new
        x = new
    return x


MIN_ODOMETER_CHECKS = 5     # increments a link measures too, to measure the odometer by
ODOMETER_STEP_FRACTION = 0.1   # without them: its noise as this fraction of its step


def odometer_noise_mm(links: Sequence[Link], odometry_mm: Mapping[int, float]) -> float:
    """The odometer's 1-sigma per increment, measured on the run.

    Every odometer increment between consecutive readings that a registration link
    measures too is compared with it: the robust spread (1.4826 MAD) of the link's dz
    less the increment times their median ratio (the odometer's scale). That spread
    holds the link's error too, which is far smaller (a tenth of a pixel); it is at
    least the links' median sigma. An odometer slip is an outlier there and does not
    widen it. An odometer that counts in steps (an encoder coarser than the frame
    step: every increment a whole number of counts, zeros included) has at least its
    rounding noise, a count / sqrt(6) per increment. With fewer than ``MIN_ODOMETER_CHECKS`` such
    increments (no common texture: the odometer alone places the frames, whatever its
    sigma), ``ODOMETER_STEP_FRACTION`` of its median increment.
    """
    readings = sorted(f for f, v in odometry_mm.items() if np.isfinite(v))
    steps = {(a, b): odometry_mm[b] - odometry_mm[a] for a, b in itertools.pairwise(readings)}
    checks = [(ln.dz_mm, steps[ln.i, ln.j], ln.dz_sigma_mm) for ln in links
              if (ln.i, ln.j) in steps]
    moved = [c for c in checks if c[1] != 0]
    if len(moved) < MIN_ODOMETER_CHECKS:
        typical = float(np.median(np.abs(list(steps.values())))) if steps else 0.0
        return max(ODOMETER_STEP_FRACTION * typical, 1e-6)
    dz, inc, link_sigma = np.array(checks).T
    scale = float(np.median([d / i for d, i, _ in moved]))
    resid = dz - scale * inc
    spread = mad_sigma(resid)
    return max(spread, float(np.median(link_sigma)), _count_noise_mm(list(steps.values())))


def _count_mm(increments: list[float]) -> float:
    """The odometer's count when the increments take several values, each a whole
    number of one count (the smallest non-zero one), else 0. Equal increments (a probe
    triggered every so many counts) say nothing of the count."""
    nonzero = np.abs([v for v in increments if v != 0])
    if len(nonzero) == 0 or len(np.unique(np.round(increments, 9))) < 2:
        return 0.0
    count = float(nonzero.min())
    counts = np.asarray(increments) / count
    return count if np.allclose(counts, np.round(counts), rtol=0, atol=1e-6) else 0.0


def _count_noise_mm(increments: list[float]) -> float:
    """The rounding noise of an increment of a counting odometer (two readings each
    rounded to a count: a count / sqrt(6)), else 0."""
    return _count_mm(increments) / np.sqrt(6.0)


MIN_SPAN_COUNTS = 10   # a counting odometer's increments span at least this many counts


def _odometer_spans(odo: Mapping[int, float]) -> list[tuple[int, int]]:
    """The pairs of readings whose increments the solve takes: consecutive ones, or for
    an odometer counting in steps as coarse as the frames' spacing, spans of at least
    ``MIN_SPAN_COUNTS`` counts (each increment's rounding is then a small part of it; a
    count per increment of 0 or 1 would otherwise pull the fitted scale towards the
    ratio of one frame step to one count)."""
    frames = sorted(odo)
    pairs = list(itertools.pairwise(frames))
    count = _count_mm([odo[b] - odo[a] for a, b in pairs])
    if not count or np.median([abs(odo[b] - odo[a]) for a, b in pairs]) >= MIN_SPAN_COUNTS * count:
        return pairs
    spans, start = [], frames[0]
    for f in frames[1:]:
        if abs(odo[f] - odo[start]) >= MIN_SPAN_COUNTS * count or f == frames[-1]:
            spans.append((start, f))
            start = f
    return spans


def solve_positions(n_frames: int, links: Sequence[Link], *,
                    odometry_mm: Mapping[int, float] | None = None,
                    odometer_sigma_mm: float | None = None, odometer_scale_sigma: float = 0.05,
                    placed: Sequence[int] | None = None) -> Positions:
    """Global robust solve of every frame's z and roll from registration links and odometry.

    Parameters
    ----------
    n_frames : int
        Frames of the run (indices 0..n-1).
    links : sequence of Link
        Registration measurements (any pairs).
    odometry_mm : mapping, optional
        Odometer reading per frame; consecutive differences (times a fitted scale,
        prior 1 ± ``odometer_scale_sigma``) are measurements with ``odometer_sigma_mm``
        (default: measured on the run, :func:`odometer_noise_mm`).
    odometer_scale_sigma : float
        1-sigma of the prior on the odometer's scale (a fraction: no unit to adapt).
    placed : sequence of int, optional
        Frames to solve for (default all); the others stay NaN.

    Returns
    -------
    Positions
        Frames not connected to the largest group by any measurement are NaN.
    """
    frames = sorted(set(range(n_frames) if placed is None else placed))
    col = {f: k for k, f in enumerate(frames)}
    n = len(frames)
    if n == 0:
        return Positions(np.full(n_frames, np.nan), np.full(n_frames, np.nan), 1.0, [])
    reg = [ln for ln in links if ln.i in col and ln.j in col]
    z_rows = [(col[ln.i], col[ln.j], ln.dz_mm, ln.dz_sigma_mm) for ln in reg]
    odo = {f: v for f, v in (odometry_mm or {}).items() if f in col and np.isfinite(v)}
    odo_pairs = _odometer_spans(odo)
    odo_extra = [(len(z_rows) + k, odo[b] - odo[a], 0.0) for k, (a, b) in enumerate(odo_pairs)]
    if odo_pairs and odometer_sigma_mm is None:
        odometer_sigma_mm = odometer_noise_mm(reg, odo)
    z_rows += [(col[a], col[b], 0.0, odometer_sigma_mm) for a, b in odo_pairs]
    n_measured = len(z_rows)
    n_extra = 1 if odo_pairs else 0
    if n_extra:
        z_rows.append((-1, n, 1.0, odometer_scale_sigma))   # scale prior: s = 1 +- sigma
    z_rows.append((-1, 0, 0.0, 1e6))   # a loose gauge; fixed below per component
    z, keep = _robust_linear(z_rows, n, n_extra, odo_extra)
    kept = keep[:n_measured]
    # Placement: frames connected to the largest group by measurements that survived.
    label = _components(n, [(i, j) for (i, j, *_), k in zip(z_rows, kept, strict=False) if k])
    # The largest group; of equal ones, that of the earliest frame (whatever the numbering).
    main = label[np.argmax(np.bincount(label)[label])]
    unplaced = label != main
    scale = float(z[n]) if n_extra else 1.0
    z = z[:n] - z[int(np.flatnonzero(~unplaced)[0])]
    # Roll from the registration links kept in z, plus weak continuity (5 deg per frame)
    # between consecutive frames so that frames tied only by the odometer get a smooth
    # guess instead of an arbitrary one; they are reported.
    reg_kept = [ln for ln, k in zip(reg, kept[:len(reg)], strict=True) if k]
    roll_label = _components(n, [(col[ln.i], col[ln.j]) for ln in reg_kept])
    placed_cols = np.flatnonzero(~unplaced)
    anchor = int(placed_cols[np.argmax(np.bincount(roll_label[placed_cols])[
        roll_label[placed_cols]])])
    r_rows = [(col[ln.i], col[ln.j], ln.droll_deg, ln.droll_sigma_deg) for ln in reg_kept]
    r_rows += [(int(a), int(b), 0.0, 5.0 * (frames[b] - frames[a]))
               for a, b in itertools.pairwise(placed_cols)]
    r_rows.append((-1, anchor, 0.0, 1e-3))
    roll, r_keep = _robust_linear(r_rows, n)
    roll_guessed = [frames[k] for k in placed_cols if roll_label[k] != roll_label[anchor]]
    z[unplaced], roll[unplaced] = np.nan, np.nan
    if odo:
        offsets = [odo[f] * scale - z[col[f]] for f in odo if np.isfinite(z[col[f]])]
        if offsets:
            z = z + float(np.median(offsets))
    outliers = [(ln.i, ln.j, "registration") for ln, k in zip(reg, kept[:len(reg)], strict=True)
                if not k]
    outliers += [(a, b, "odometer") for (a, b), k in zip(odo_pairs, kept[len(reg):],
                                                           strict=True) if not k]
    outliers += [(ln.i, ln.j, "registration roll")
                 for ln, k in zip(reg_kept, r_keep[:len(reg_kept)], strict=True) if not k]
    z_all = np.full(n_frames, np.nan)
    r_all = np.full(n_frames, np.nan)
    z_all[frames], r_all[frames] = z, roll
    return Positions(z_all, r_all, scale, outliers, roll_guessed,
                     odometer_sigma_mm=odometer_sigma_mm if odo_pairs else float("nan"))
