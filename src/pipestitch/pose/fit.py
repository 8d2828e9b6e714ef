"""Ring points -> probe pose hypotheses (both mirror solutions, always).

Ring pixels are unprojected to rays and intersected with the known laser plane
z = d, which gives exact 3-D points: no iteration over the pose is needed to get
them. In the plane the ring is a conic, q(u) = A u + c on the wall |q| = r, with
A the top-left 2 × 2 block of R = Rx(alpha)·Ry(beta) and c the plane centre's
world offset. Because R is a rotation, A^T A = I - w w^T with
w = (-cos(alpha) sin(beta), sin(alpha)) the pipe axis seen from the probe. An
ellipse fitted to the plane points therefore gives |w| (from its axis ratio), the
direction of w up to sign (its minor axis), the radius and the offset: a closed
form for both hypotheses, w and -w, which are exactly the mirror ambiguity
(alpha, beta) <-> (-alpha, -beta) with another offset. Both are then refined by
robust least squares (soft-L1 loss as ``scipy.optimize.least_squares`` defines it,
analytic Jacobian) of the radial distance of every plane point from the wall, in mm.

Outliers (glints, reflections, second candidates on a ray) are removed by RANSAC
on the ellipse (seeded, as ``skimage.measure.ransac`` does it) when the strongest
candidates do not already agree, then by re-selecting one candidate per ray by its
distance from the conic until the set is stable. This module fits one frame;
choosing between the hypotheses over a run is :mod:`pipestitch.pose.ambiguity`.

The loops over the points are compiled (:mod:`pipestitch.pose._fit_kernels`, and the
camera models' unprojection): a frame takes a few tenths of a millisecond.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, plane_basis
from pipestitch.pose import _fit_kernels as _k
from pipestitch.pose.ring import RingDetection

__all__ = [
    "ConicModel",
    "Hypothesis",
    "LaserPlane",
    "PoseFit",
    "RingPoints",
    "fit_pose",
    "frame_noise_mm",
    "model_conic",
    "plane_points",
    "plane_to_world",
    "pose_from_conic",
    "ring_rms_px",
    "ring_scale_mm_per_px",
]

PARAMS = ("alpha", "beta", "dx_mm", "dy_mm", "radius_mm")
# The point noise a frame is fitted with, its gates and their widening (fit_pose): the
# kernels' constants, documented there (pose/_fit_kernels.py).
NOISE_PER_LINE_SIGMA = _k.NOISE_PER_LINE_SIGMA
GATE_SIGMAS = _k.GATE_SIGMAS
RESELECT_SIGMAS = _k.RESELECT_SIGMAS
RESCALE_RMS = _k.RESCALE_RMS
RESCALE_ROUNDS = _k.RESCALE_ROUNDS
FALLBACK_NOISE_MM = _k.FALLBACK_NOISE_MM
RANSAC_TRIALS = 200   # at most; fewer once the best inlier ratio makes a clean sample sure
KEPT_POINTS = 720     # a frame's ring inliers kept for later fits (RingPoints), at most


# The fit's result types (Hypothesis, RingPoints, PoseFit) are slotted dataclasses, not
# frozen ones, and are read-only by convention (nothing assigns to them after the fit): a
# frozen dataclass sets each field through object.__setattr__, and right after a ring
# extraction, with that path's code cold, a frame's four such objects took ~15 us more
# (table1's protocol, paired), ~6 % of the fit.
@dataclass(slots=True)
class Hypothesis:
    """One pose solution of a frame.

    Attributes
    ----------
    pose : Pose
        alpha, beta, dx, dy (roll and z are 0: the ring cannot see them).
    radius_mm : float
        Local pipe radius from the ring.
    cost : float
        Robust least-squares cost at the solution (0.5 · sum of rho(residual²)).
    rms_mm, rms_px : float
        RMS residual of the inliers, on the wall (mm) and in the image (px).
    std : dict
        One-sigma uncertainty of each parameter (radians for angles, mm), as if the ring
        points' residuals were independent (what the pose step's tests were made with).
    information : numpy.ndarray or None
        4 x 4 information matrix (inverse covariance) of (alpha, beta, dx, dy) from the
        ring, the radius marginalised out: what the ring says about the pose, for fusing
        with other evidence (:mod:`pipestitch.mosaic.refine`).
    std_scale : float
        How many times wider the uncertainty is, the residuals' correlation along the
        ring counted (the square root of
        :func:`pipestitch.pose._fit_kernels.correlation_factor`): the output files'
        standard deviations are ``std`` times this.
    std_override : dict
        One-sigma uncertainties (same keys and units as ``std``) stated instead of the
        ring's: the refinement's once the LED frames refined the pose
        (:mod:`pipestitch.mosaic.refine`), the ring's widened where the pipe's radius
        changes along it (:func:`pipestitch.pose.section.sloping_wall_spread`); empty
        otherwise.
    """

    pose: Pose
    radius_mm: float
    cost: float
    rms_mm: float
    rms_px: float
    std: dict[str, float] = field(default_factory=dict)
    information: np.ndarray | None = field(default=None, compare=False)
    section: PipeSection | None = None
    std_scale: float = 1.0
    std_override: dict[str, float] = field(default_factory=dict)

    @property
    def stated_std(self) -> dict[str, float]:
        """``std`` times ``std_scale``, ``std_override`` in place of its entries: the
        standard deviations the output files state."""
        return {k: v * self.std_scale for k, v in self.std.items()} | self.std_override

    @property
    def pipe_section(self) -> PipeSection:
        """The fitted cross-section: an oval when one was fitted, else the circle."""
        return self.section if self.section is not None else PipeSection(self.radius_mm)


@dataclass(slots=True)
class RingPoints:
    """A frame's ring inliers, kept for later fits (subsampled to at most 720).

    ``uv`` are in-plane coordinates (mm), ``pixels`` the image points they came from.
    """

    uv: np.ndarray
    pixels: np.ndarray
    plane: LaserPlane
    noise_mm: float = 0.05   # the point noise the fit took (:func:`fit_pose`); refits reuse it

    @property
    def points_mm(self) -> np.ndarray:
        """(N, 3) probe-frame points on the laser plane (float64)."""
        return self.plane.to_probe(self.uv.astype(np.float64))

    def without_pixels(self) -> RingPoints:
        """The same plane points without their image pixels (what later fits read)."""
        return RingPoints(self.uv, self.pixels[:0].copy(), self.plane, self.noise_mm)


@dataclass(slots=True)
class PoseFit:
    """Result of fitting one laser frame: both hypotheses or a reason why not.

    ``hypotheses[1]`` is the mirror of ``hypotheses[0]``; their order carries no
    preference. ``ok`` is False (with ``reason``) when no fit was possible.
    """

    ok: bool
    reason: str
    hypotheses: tuple[Hypothesis, ...] = ()
    n_points: int = 0
    coverage: float = 0.0
    model: str = "circle"
    ring: RingPoints | None = field(default=None, compare=False)


@dataclass(frozen=True)
class LaserPlane:
    """The laser plane n·p = d in the probe frame (SPEC: n = +z, i.e. z = d).

    ``basis`` holds two unit vectors spanning the plane
    (:func:`pipestitch.geometry.plane_basis`; probe x and y for SPEC's plane), so a
    plane point is d·n + u[0]·basis[0] + u[1]·basis[1].
    """

    distance_mm: float
    normal: np.ndarray
    basis: np.ndarray   # (2, 3): the in-plane unit vectors e1, e2

    @classmethod
    def of(cls, distance_mm: float, normal: np.ndarray | None = None) -> LaserPlane:
        """Plane at ``distance_mm`` with the given normal (default SPEC's +z)."""
        n = (0.0, 0.0, 1.0) if normal is None else tuple(float(v) for v in np.ravel(normal))
        return _laser_plane(float(distance_mm), n)

    def to_probe(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) in-plane coordinates -> (N, 3) probe-frame points, mm."""
        return self.distance_mm * self.normal + uv @ self.basis


@functools.lru_cache(maxsize=64)
def _laser_plane(distance_mm: float, normal: tuple[float, ...]) -> LaserPlane:
    n = np.asarray(normal) / np.linalg.norm(normal)
    plane = LaserPlane(distance_mm, n, np.array(plane_basis(n)))
    plane.normal.flags.writeable = plane.basis.flags.writeable = False  # shared: read-only
    return plane


def plane_points(pixels: np.ndarray, camera: CameraModel, plane_distance_mm: float,
                 plane_normal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the rays of ring pixels with the laser plane n·p = d.

    Returns
    -------
    points : numpy.ndarray, shape (M, 2)
        In-plane coordinates, mm (probe x, y for SPEC's plane z = d).
    valid : numpy.ndarray of bool, shape (N,)
        Which pixels gave a point (ray in front of the plane, inside the lens).
    """
    uv, valid = _plane_coords(pixels, camera, LaserPlane.of(plane_distance_mm, plane_normal))
    return uv[valid], valid


class ConicModel:
    """General conic a x² + b xy + c y² + d x + e y + f = 0 (``skimage.measure.ransac`` API).

    Written here rather than using ``skimage.measure.EllipseModel`` because that
    model's residuals are iterative per-point geometric distances: over hundreds of
    RANSAC trials and thousands of candidates that costs seconds per frame. This is
    the algebraic fit (smallest eigenvector of the scatter, on coordinates normalised
    to unit scale) with the first-order (Sampson) distance as residual, which is
    accurate to well under the inlier threshold near the curve. :func:`fit_pose`
    runs the same fit and RANSAC compiled (:mod:`pipestitch.pose._fit_kernels`).
    """

    def __init__(self) -> None:
        self.coef = np.zeros(6)
        self.scale = 1.0

    @classmethod
    def from_estimate(cls, data: np.ndarray) -> ConicModel | None:
        """A fitted model, or None when the points do not make an ellipse (skimage API)."""
        model = cls()
        return model if model.estimate(data) else None

    def estimate(self, data: np.ndarray) -> bool:
        """Fit the conic to (N >= 5, 2) points; False if it is not an ellipse."""
        data = _as_points(data)
        coef, scale, ok = _k.conic_fit(data, np.ones(len(data), bool))
        if ok:  # not an ellipse: the model keeps its previous conic
            self.coef, self.scale = coef, scale
        return ok

    def residuals(self, data: np.ndarray) -> np.ndarray:
        """Sampson distance of each point from the conic (data units)."""
        return _k.sampson(_as_points(data), self.coef, self.scale)

    def normalised(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(Q, lin, c0) in data units with u^T Q u + 2 lin^T u + c0 = 0, max eig(Q) = 1."""
        q, lin, c0 = _k.conic_normalised(self.coef, self.scale)
        return q, lin, float(c0)


def _as_index(data: np.ndarray) -> np.ndarray:
    """Integer array as the kernels take it (int64), copied only when it is not one."""
    return data if isinstance(data, np.ndarray) and data.dtype == np.int64 else np.asarray(
        data, dtype=np.int64)


def _as_points(data: np.ndarray) -> np.ndarray:
    """(N, k) float64, C-contiguous: one compiled signature for every caller."""
    return np.ascontiguousarray(data, dtype=np.float64)


def pose_from_conic(q: np.ndarray, lin: np.ndarray, c0: float, plane_distance_mm: float,
                    plane_normal: np.ndarray | None = None) -> list[tuple[Pose, float]]:
    """Closed-form poses (both mirrors) and radius from the ring's conic in the plane.

    Parameters
    ----------
    q, lin, c0 : conic u^T q u + 2 lin^T u + c0 = 0 in in-plane coordinates u
        (:func:`plane_points`), normalised so max eig(q) = 1.
    plane_distance_mm : float
        Laser plane distance d.
    plane_normal : numpy.ndarray, optional
        Plane normal in the probe frame (default SPEC's +z).

    Returns
    -------
    list of (Pose, radius_mm)
        Two entries, w and -w; empty if the conic is not an ellipse of this form.

    Notes
    -----
    With P the plane basis (3 x 2), a wall point's world (x, y) is A u + c with
    A = (R P)[:2]; A^T A = I - w w^T where w = P^T a and a = R^T e_z is the pipe
    axis in the probe frame. The conic's minor axis gives w up to sign, and
    a = P w + sqrt(1 - |w|²) n (the axis points forward, like the normal).
    """
    plane = LaserPlane.of(plane_distance_mm, plane_normal)
    sols = _k.conic_poses(_as_points(q), _as_points(lin), float(c0), _kernel_plane(plane))
    return [(Pose(*(float(v) for v in s[:4])), float(s[4])) for s in sols]


def model_conic(pose: Pose, radius_mm: float, plane: LaserPlane) -> tuple[np.ndarray, np.ndarray,
                                                                          float]:
    """The ring conic (q, lin, c0) in plane coordinates that a pose and radius predict.

    Inverse of :func:`pose_from_conic`: both mirror poses give the same conic.
    """
    q, lin, c0 = _k.model_conic(_pose_vector(pose, radius_mm), _kernel_plane(plane))
    return q, lin, float(c0)


def plane_to_world(pose: Pose, plane: LaserPlane) -> tuple[np.ndarray, np.ndarray]:
    """(A, c): a plane point u (in-plane coordinates) lies at world (x, y) = A u + c."""
    return _k.plane_to_world(_pose_vector(pose, 0.0), _kernel_plane(plane))


def _kernel_plane(plane: LaserPlane) -> _k.Plane:
    """The plane as the kernels take it (float distance: one compiled signature)."""
    return _k.Plane(float(plane.distance_mm), plane.normal, plane.basis)


def _pose_vector(pose: Pose, radius_mm: float) -> np.ndarray:
    """(alpha, beta, dx, dy, radius): the kernels' pose vector."""
    return np.array([pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm, radius_mm], dtype=np.float64)


def fit_pose(detection: RingDetection, camera: CameraModel, plane_distance_mm: float, *,
             nominal_radius_mm: float | None = None, fit_radius: bool = True,
             min_coverage: float = 0.25, noise_mm: float | None = None,
             plane_normal: np.ndarray | None = None, seed: int = 0) -> PoseFit:
    """Fit both pose hypotheses to one frame's ring candidates.

    Parameters
    ----------
    detection : RingDetection
        Ring candidates (:func:`pipestitch.pose.ring.detect_ring`).
    camera : CameraModel
        Camera model.
    plane_distance_mm : float
        Laser plane distance d.
    nominal_radius_mm : float, optional
        Pipe radius to use when ``fit_radius`` is False.
    fit_radius : bool
        Estimate the local pipe radius (default) or hold it at the nominal value.
    min_coverage : float
        Minimum fraction of azimuths with an inlier for a fit to be accepted.
    noise_mm : float, optional
        Point noise on the laser plane (mm): the robust loss scale; the inlier gates are
        6 and 5 of it. Default: from the frame itself, the line's measured width times
        ``NOISE_PER_LINE_SIGMA`` mapped to the plane by the local pixel -> plane scale
        at the ring (:func:`ring_scale_mm_per_px`), then widened from the fit's own
        residuals while the inliers scatter more than ``RESCALE_RMS`` of it; so the
        same code fits at any pipe size, plane distance, lens and line width.
    plane_normal : numpy.ndarray, optional
        Calibrated laser-plane normal in the probe frame (default SPEC's +z).
    seed : int
        Seed of the RANSAC sampler (results are deterministic).

    Returns
    -------
    PoseFit
        ``ok`` False with a reason when the frame has no usable ring.
    """
    if not fit_radius and nominal_radius_mm is None:
        raise ValueError("fit_pose: nominal_radius_mm is needed when fit_radius is False")
    radius = math.nan if fit_radius else float(nominal_radius_mm)
    noise = math.nan if noise_mm is None else float(noise_mm)
    # plain numbers: the settings are built from what keys them (_constant_arguments)
    plane, constant = _constant_arguments(camera, float(plane_distance_mm), plane_normal,
                                          noise, float(min_coverage), radius,
                                          int(detection.n_azimuths))
    try:
        noise, out = _fit(detection, constant, camera, seed)
    except np.linalg.LinAlgError:   # singular normal equations: the points span too little
        return PoseFit(False, "degenerate ring (the points do not determine a pose)",
                       coverage=detection.coverage)
    if out.status == _k.NO_RING:
        return PoseFit(False, f"ring not found (coverage {out.coverage:.0%})",
                       coverage=out.coverage)
    coverage = out.rays_hit / detection.n_azimuths
    if out.status != _k.FOUND:
        reason = {_k.NO_ELLIPSE: "no ellipse found among ring candidates",
                  _k.NOT_A_SECTION: "ring is not the section of a cylinder"}.get(
            out.status, f"too few ring points fit ({coverage:.0%} of the ring)")
        return PoseFit(False, reason, coverage=coverage if out.status == _k.LOW_COVERAGE
                       else out.coverage)
    # the ring's inliers kept: <= KEPT_POINTS, float32, <= 12 kB a frame
    return PoseFit(True, "", _hypotheses(out.summary, out.cost, out.rms_px, out.information),
                   out.n_kept, coverage, "circle",
                   RingPoints(out.ring_uv, out.ring_pixels, plane, noise))


def ring_scale_mm_per_px(detection: RingDetection, camera: CameraModel,
                         plane: LaserPlane, *, n_points: int = _k.RING_SCALE_POINTS) -> float:
    """How far a one-pixel step across the ring moves on the laser plane (mm), median
    over up to ``n_points`` of the rays' strongest candidates.

    The step is taken normal to the ring in the image (the ring's tangent from the
    neighbouring candidates, in azimuth order): the direction in which the detector
    localises the line. NaN when no candidate meets the plane.
    """
    on_plane = _kernel_plane(plane)
    candidates = _candidates(detection)
    kernel = getattr(camera, "ray_kernel", None)
    if kernel is not None:
        return _k.ring_scale(candidates, kernel, on_plane, n_points)
    query, valid = _k.across_query(candidates, n_points)
    if valid.size == 0:
        return math.nan
    return _k.median_step(_as_points(camera.unproject(query)), valid, on_plane)


def _candidates(detection: RingDetection) -> _k.Candidates:
    """A detection's ring candidates as the kernels take them."""
    return _k.Candidates(_as_points(detection.pixels), _as_index(detection.azimuth),
                         _as_index(detection.rank), int(detection.n_azimuths))


def frame_noise_mm(detection: RingDetection, camera: CameraModel, plane: LaserPlane) -> float:
    """A frame's prior ring-point noise on the laser plane (mm): ``NOISE_PER_LINE_SIGMA``
    of the measured line width, through :func:`ring_scale_mm_per_px` (the noise
    :func:`fit_pose` starts from; NaN without a scale or a width)."""
    scale, sigma_px = ring_scale_mm_per_px(detection, camera, plane), detection.line_sigma_px
    if not (math.isfinite(scale) and math.isfinite(sigma_px)):
        return math.nan
    return NOISE_PER_LINE_SIGMA * sigma_px * scale


@functools.lru_cache(maxsize=64)
def _min_rays(min_coverage: float, n_azimuths: int) -> int:
    """Fewest rays hit with ``hit / n_azimuths >= min_coverage`` (the float test itself:
    ``ceil(c * n)`` is one too many where the product rounds up, 0.55 * 100 = 55.0…07)."""
    hit = max(0, math.ceil(min_coverage * n_azimuths))
    while hit > 0 and (hit - 1) / n_azimuths >= min_coverage:
        hit -= 1
    while n_azimuths and hit / n_azimuths < min_coverage:
        hit += 1
    return hit


class KernelFit(NamedTuple):
    """The fit kernel's result for a frame (:func:`pipestitch.pose._fit_kernels.fit_frame`),
    by name; the arrays are empty unless ``status`` is FOUND."""

    coverage: float           # of the detection: rays with a candidate
    status: int               # _fit_kernels.FOUND, NO_RING, NO_ELLIPSE, ...
    rays_hit: int             # rays with a kept ring point
    n_kept: int               # ring points kept
    summary: np.ndarray       # (2, ...): each hypothesis' pose, rms_mm, ok flag, sigmas
    cost: float
    rms_px: float
    information: np.ndarray   # (2, 4, 4)
    ring_uv: np.ndarray       # the kept points (subsampled), plane coordinates, float32
    ring_pixels: np.ndarray   # ... and their image pixels


class _Constant(NamedTuple):
    """What a frame's fit takes that its ring does not change (:func:`_constant_arguments`)."""

    plane: _k.Plane
    settings: _k.FitSettings
    fields: tuple | None   # fit_fields' arguments from n_azimuths to before the sigma


# The fit's constant arguments by camera and settings (every frame of a run shares one
# entry). Each entry holds its camera, so no other camera can take its id meanwhile.
_CONSTANT: dict[tuple, tuple[CameraModel, LaserPlane, _Constant]] = {}
_CONSTANT_ENTRIES = 64   # at most; then the dictionary starts again
_NO_SAMPLES = np.empty((0, 5))   # RANSAC's samples before they are drawn (_fit); never written


def _constant_arguments(camera: CameraModel, plane_distance_mm: float,
                        plane_normal: np.ndarray | None, noise_mm: float, min_coverage: float,
                        radius: float, n_azimuths: int) -> tuple[LaserPlane, _Constant]:
    """The laser plane and the fit kernel's arguments that depend on the camera, the
    plane and the settings only (:func:`fit_pose`'s, as Python numbers; ``noise_mm``
    and ``radius`` NaN: from the frame), built once for each combination.

    Right after a ring extraction the Python that builds them is cold: ~17 us a frame
    (table1's frames) that a dictionary look-up replaces.
    """
    normal = None if plane_normal is None else tuple(np.ravel(plane_normal).tolist())
    # NaN is a key by None: one NaN object is not equal to another
    key = (id(camera), plane_distance_mm, normal, noise_mm if noise_mm == noise_mm else None,
           min_coverage, radius if radius == radius else None, n_azimuths)
    entry = _CONSTANT.get(key)
    if entry is None:
        plane = LaserPlane.of(plane_distance_mm, plane_normal)
        on_plane = _kernel_plane(plane)
        settings = _fit_settings(noise_mm, min_coverage, radius, n_azimuths)
        kernel = getattr(camera, "ray_kernel", None)
        fields = None if kernel is None else (int(n_azimuths), *kernel, *on_plane, *settings)
        if len(_CONSTANT) >= _CONSTANT_ENTRIES:
            _CONSTANT.clear()
        entry = _CONSTANT[key] = (camera, plane, _Constant(on_plane, settings, fields))
    return entry[1], entry[2]


def _fit(detection: RingDetection, constant: _Constant, camera: CameraModel,
         seed: int) -> tuple[float, KernelFit]:
    """(noise, the fit kernel's result) for a frame (:class:`KernelFit`).

    ``constant.settings.noise_mm`` NaN takes the noise from the frame: its candidates
    and the line's measured sigma, widened from the fit's residuals
    (:func:`pipestitch.pose._fit_kernels.fit_scaled`). What is unprojected
    (:func:`pipestitch.pose._fit_kernels.fit_query`): the candidates, then every
    ``stride``-th one moved one column, then one row (before the fit it is not known
    which candidates are the ring, and on a ring without outliers these are the points
    :func:`ring_rms_px` takes of the inliers), then the points the frame's pixel ->
    plane scale is measured at: one unprojection for all, as each call has a fixed
    cost. A camera with a compiled unprojection (``ray_kernel``) is unprojected inside
    the one kernel call (:func:`pipestitch.pose._fit_kernels.fit_fields`), any other
    through its ``unproject``.

    Selection: a first conic directly when the strongest candidates agree (most frames
    have few outliers, and one algebraic fit of every ray's strongest candidate then
    explains 90 % of them); otherwise RANSAC, with samples from a generator seeded with
    ``seed`` (reproducible), drawn only then. Inliers are then re-selected among all
    candidates, one per ray, until the set is stable (the start may have missed a
    stretch of the ring); the conic's Sampson distance is accurate to microns near the
    curve, so this needs no nonlinear fit. ``constant.settings.radius_mm`` NaN fits the
    radius, else holds it. Refinement: :func:`_hypotheses`.
    """
    found, noise, out = _fit_with(detection, constant, camera, _NO_SAMPLES)
    if out[0] == _k.NEEDS_SAMPLES:
        found, noise, out = _fit_with(detection, constant, camera, np.random.default_rng(
            seed).random((RANSAC_TRIALS, 5)))
    return noise, KernelFit(found, *out)


def _fit_with(detection: RingDetection, constant: _Constant, camera: CameraModel,
              uniforms: np.ndarray) -> tuple[float, float, tuple]:
    """(coverage, noise, :func:`pipestitch.pose._fit_kernels.fit_frame`'s tuple) of one
    kernel pass with RANSAC's samples ``uniforms`` (:func:`_fit`)."""
    sigma = float(detection.line_sigma_px)
    if constant.fields is not None:
        # the candidates' arrays as _candidates converts them, without its named tuple:
        # built cold after each ring extraction, it costs ~4 us of a fit (table1's frames)
        return _k.fit_fields(_as_points(detection.pixels), _as_index(detection.azimuth),
                             _as_index(detection.rank), *constant.fields, sigma, uniforms)
    candidates = _candidates(detection)
    query, stride, found, valid = _k.fit_query(candidates)
    if not _k.has_ring(candidates, found, constant.settings):
        return found, math.nan, _k.no_fit(_k.NO_RING, 0, constant.settings.n_free)
    rays = _as_points(camera.unproject(query))
    return found, *_k.fit_scaled(rays, stride, valid, candidates, constant.plane,
                                 constant.settings, sigma, uniforms)


def _fit_settings(noise_mm: float, min_coverage: float, radius: float,
                  n_azimuths: int) -> _k.FitSettings:
    """The fit kernel's settings for a frame with point noise ``noise_mm`` (NaN: from
    the frame); ``radius`` NaN fits the radius, else holds it. Python floats and ints:
    one compiled signature."""
    return _k.FitSettings(noise_mm=float(noise_mm), radius_mm=float(radius),
                          n_free=4 if radius == radius else 5,
                          min_coverage=float(min_coverage),
                          min_hit=_min_rays(min_coverage, n_azimuths), max_points=KEPT_POINTS)


def _hypotheses(summary: np.ndarray, cost: float, rms_px: float,
                info: np.ndarray) -> tuple[Hypothesis, Hypothesis]:
    """The refined hypothesis and its mirror, the other pose of the refined conic.

    ``summary`` is :func:`pipestitch.pose._fit_kernels.refine_frame`'s: a row per hypothesis.
    Both mirrors explain every plane point with the same residual (the same conic), so
    the optimum of one maps to the optimum of the other in closed form. The robust
    least squares is a damped IRLS Gauss-Newton on the soft-L1 loss
    (:func:`pipestitch.pose._fit_kernels.gauss_newton`), not
    ``scipy.optimize.least_squares``, whose per-call set-up alone cost ~3 ms per
    hypothesis (measured) for 4-5 parameters; from the closed-form start one or two
    iterations reach a step far below the noise. Both share one px RMS: they are the
    same curve in the image.
    """
    # one conversion to Python floats, both hypotheses written out: indexing the arrays
    # element by element, or a loop over the two, costs more here (right after a ring
    # extraction every distinct call is cold)
    a, b = summary.tolist()
    rms, ok, sig, corr = _k.SUMMARY_RMS, _k.SUMMARY_OK, _k.SUMMARY_SIGMA, _k.SUMMARY_CORR
    return (Hypothesis(Pose(a[0], a[1], a[2], a[3]), a[4], cost, a[rms], rms_px,
                       dict(zip(PARAMS, a[sig:], strict=False)) if a[ok] else {}, info[0],
                       std_scale=math.sqrt(a[corr])),
            Hypothesis(Pose(b[0], b[1], b[2], b[3]), b[4], cost, b[rms], rms_px,
                       dict(zip(PARAMS, b[sig:], strict=False)) if b[ok] else {}, info[1],
                       std_scale=math.sqrt(b[corr])))


def ring_rms_px(pose: Pose, radius: float, pixels: np.ndarray, uv: np.ndarray,
                resid_mm: np.ndarray, camera: CameraModel, plane: LaserPlane) -> float:
    """RMS image distance between observed points and the model ring at the same angle.

    To first order in the residual (tens of microns): a point's radial residual on the
    wall is moved back along its ray in the plane (direction u/|u| from the plane
    centre) and the plane offset is turned into pixels with the local pixel -> plane
    Jacobian (finite differences of the unprojection, one pixel apart). Projecting the
    model ring instead costs a lens-polynomial inversion per point.

    Parameters
    ----------
    pose : Pose
        The pose of the model ring.
    radius : float
        Its radius, mm (unused by the first-order form; kept for the callers).
    pixels, uv : numpy.ndarray, shape (N, 2)
        Observed ring pixels (col, row) and their in-plane coordinates (mm).
    resid_mm : numpy.ndarray, shape (N,)
        Radial wall residual of each point at the pose, mm.
    camera : CameraModel
        Camera model.
    plane : LaserPlane
        The laser plane.

    Returns
    -------
    float
        RMS in pixels (NaN if no point could be converted).
    """
    sub = slice(None, None, _rms_stride(len(uv)))
    px = np.asarray(pixels, dtype=np.float64)[sub]
    # one unprojection for both one-pixel steps (column, then row)
    moved = _plane_coords(np.concatenate([px + [1.0, 0.0], px + [0.0, 1.0]]), camera, plane)[0]
    a_mat, c = plane_to_world(pose, plane)
    return float(_k.px_rms(_as_points(uv[sub]), _as_points(resid_mm[sub]), moved[:len(px)],
                           moved[len(px):], a_mat, c))


def _rms_stride(n: int) -> int:
    """Subsampling of n points for the px RMS, as the fit takes it (``RMS_POINTS``)."""
    return max(1, n // _k.RMS_POINTS)


def _plane_coords(pixels: np.ndarray, camera: CameraModel,
                  plane: LaserPlane) -> tuple[np.ndarray, np.ndarray]:
    """In-plane coordinates of each pixel's ray (NaN where it misses the plane), and the mask.

    A camera with a compiled unprojection (``ray_kernel``) is unprojected by it (a few
    points cost its per-call overhead, not the model's array set-up).
    """
    kernel = getattr(camera, "ray_kernel", None)
    rays = (_k.rays_of(kernel, _as_points(pixels)) if kernel is not None
            else _as_points(camera.unproject(pixels)))
    return _k.rays_to_plane(rays, _kernel_plane(plane))
