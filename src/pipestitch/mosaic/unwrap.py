"""Centralised unwrapping: an LED frame + its pose -> a strip of the wall in (theta, z).

For every node of an output grid over the wall (theta around the pipe, z along it,
relative to the camera's axial position and with roll 0) the wall point is moved
into the probe frame by the frame's pose, projected by the camera model and the
frame is sampled there with ``cv2.remap``: one resampling, straight from wall to
pixel, so the strip has a true millimetre scale whatever the probe's tilt and
offset. Nodes outside the lens' valid range or the image are masked (NaN); occluders
inside the image (mirror assembly, laser-holder arm) are not known from probe.toml
and are left to the caller (see :mod:`pipestitch.mosaic.photometric`).

Besides the maps it gives each output node a quality weight (how many source
pixels it draws on, and how squarely the camera sees the wall there), chooses the
axial window worth unwrapping from the camera and the pipe, and provides the
prior-art baseline: a polar unwrap about the image centre that assumes a centred
probe.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, RadiusProfile, WallGrid
from pipestitch.imaging import gaussian_blur
from pipestitch.mosaic._unwrap_kernels import (
    MapFields,
    contrast_of,
    fill_invalid,
    mask_strip,
    node_fields,
    node_points,
    upsample_maps,
)

__all__ = ["PackedMask", "Strip", "UnwrapMaps", "default_mm_per_px", "local_contrast",
           "local_contrast_and_mean", "pack_mask", "polar_unwrap_maps", "seen_window_mm",
           "strip_window_mm", "unwrap", "unwrap_maps", "unwrap_with_quality"]


def _node_count(n: int, step: int) -> int:
    """How many of ``n`` rows or columns :func:`_grid_points` takes as nodes: every
    ``step``-th and the last."""
    return -(-(n - 1) // step) + 1


def _column_z(grid: WallGrid, step: int, columns: np.ndarray) -> np.ndarray:
    """The z (mm) of node ``columns`` (int64 indices), each to the bit whatever the
    other indices given."""
    return grid.z0_mm + columns * step * grid.mm_per_px_axial


def _grid_points(grid: WallGrid, section: PipeSection, pose: Pose, step: int,
                 profile: RadiusProfile | None = None, columns: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nodes of every ``step``-th row and column (the last ones always included).

    Returns the wall points of the rows' ring at z = 0 (rows, 3), the columns' z
    (cols,), their scale about the axis (cols,; ones without ``profile``) and the nodes
    in the probe frame (rows · cols, 3), row after row; with ``columns`` (indices of
    node columns, int64) those columns only, their z to the bit as in the whole grid's.
    The wall's section depends on theta alone (scaled about the axis by ``profile`` at
    each column's z) and the world-to-probe map is affine, so the ring is mapped once
    and each column scales it about the axis and adds z times the pipe axis seen from
    the probe (:func:`~pipestitch.mosaic._unwrap_kernels.node_points`).
    """
    z = _column_z(grid, step, np.arange(_node_count(grid.n_cols, step)) if columns is None
                  else columns)
    ring = _ring(float(section.a_mm), float(section.b_mm), float(section.angle),
                 float(grid.theta0_deg), float(grid.deg_per_px), int(step),
                 _node_count(grid.n_rows, step))
    # Pose.to_probe's (p - t) @ R, with R and t made once for the ring and the axis
    rotation, translation = pose.rotation_world_probe(), pose.translation_world_probe()
    axis = rotation[2]   # world z in the probe frame: to_probe's row 2
    seen = (ring - translation) @ rotation
    if profile is None:
        return ring, z, np.ones_like(z), node_points(seen, z, axis, np.zeros(3), np.empty(0))
    origin = ((np.zeros((1, 3)) - translation) @ rotation)[0]   # the pipe axis at z = 0
    scale = np.asarray(profile.at(z), float)
    return ring, z, scale, node_points(seen, z, axis, origin, scale)


@functools.lru_cache(maxsize=256)
def _ring(a_mm: float, b_mm: float, angle: float, theta0_deg: float, deg_per_px: float,
          step: int, n_rows: int) -> np.ndarray:
    """The wall points (rows, 3) at z = 0 of the section (``a_mm``, ``b_mm``, ``angle``)
    at every ``step``-th row of a grid from ``theta0_deg`` at ``deg_per_px``, ``n_rows``
    of them; read-only: a run's strips share a few sections and grids (the same ring in
    a third of the calls). Keyed by plain numbers: the same values, the same ring."""
    theta = np.deg2rad(theta0_deg + np.arange(n_rows) * step * deg_per_px)
    ring = PipeSection(a_mm, b_mm, angle).points(theta, np.zeros_like(theta))
    ring.flags.writeable = False
    return ring


@dataclass(frozen=True)
class UnwrapMaps:
    """Where every node of a strip grid is seen in the frame, and how well.

    Attributes
    ----------
    map_x, map_y : numpy.ndarray
        float32 (n_rows, n_cols) pixel column/row for ``cv2.remap``; -1 where invisible.
    quality : numpy.ndarray
        float32 (n_rows, n_cols): source pixels per output pixel (the smaller of the two
        directions) times the cosine of the viewing angle on the wall; 0 where invisible.
    shading : numpy.ndarray
        float32 (n_rows, n_cols): irradiance from LEDs at the camera centre,
        cos(viewing angle) · (grid radius / distance)², 1 for a wall seen squarely at
        the grid's radius (the run's: one reference for every strip); dividing a strip
        by it leaves albedo times the lens' vignetting.
    """

    map_x: np.ndarray
    map_y: np.ndarray
    quality: np.ndarray
    shading: np.ndarray


def unwrap_maps(camera: CameraModel, pose: Pose, section: PipeSection, grid: WallGrid, *,
                step: int = 1, with_quality: bool = False,
                profile: RadiusProfile | None = None
                ) -> tuple[np.ndarray, np.ndarray] | UnwrapMaps:
    """``cv2.remap`` maps (float32, (n_rows, n_cols)) from the strip to the frame.

    Invisible nodes get -1 (outside the image), so remap returns the border value.

    Parameters
    ----------
    camera, pose, section, grid
        Lens, frame pose (its roll and z are ignored: the grid is in the frame's own
        (theta, z)), pipe cross-section and output grid.
    step : int
        Project only every ``step``-th node exactly and interpolate between them
        (the map is smooth: with step 4 the interpolation error is ~0.03 px
        at most, where the wall is seen closest, see the tests); 1 projects every node.
    with_quality : bool
        Also return the quality weight (an :class:`UnwrapMaps`).
    profile : RadiusProfile, optional
        The wall's scale of ``section`` along the grid's z (the frame's own: a
        reducer ahead of or behind the camera); default the section everywhere.
    """
    nodes, _ = _node_fields(camera, pose, section, grid, step, with_quality, profile)
    # float32 keeps pixel positions to ~1e-4 px: ample, and the maps are float32 anyway.
    # Bilinear upsampling with exact weights (cv2.resize/remap quantise them to 1/32,
    # which would cost ~0.05 px on a map that moves several pixels per coarse cell);
    # nodes whose interpolated validity is not ~1 are masked (-1, quality 0).
    maps = upsample_maps(nodes, step=step, n_rows=grid.n_rows, n_cols=grid.n_cols,
                         ok_above=0.999)
    if not with_quality:
        return maps.map_x, maps.map_y
    return UnwrapMaps(maps.map_x, maps.map_y, maps.quality, maps.shading)


def _node_fields(camera: CameraModel, pose: Pose, section: PipeSection, grid: WallGrid,
                 step: int, with_quality: bool, profile: RadiusProfile | None = None,
                 columns: np.ndarray | None = None) -> tuple[MapFields, np.ndarray]:
    """The maps' fields at every ``step``-th node (see :func:`_grid_points`; only the
    node ``columns`` given, as if they were neighbours), and the nodes' column z.

    Pixel column and row (0 where invisible), validity (1/0) and, ``with_quality``, the
    quality and the shading of :class:`UnwrapMaps` (else None), each (node rows, node
    columns).
    """
    # Roll and axial position are those of the strip's own frame: zero by construction.
    local = Pose(pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm)
    ring, z, scale, probe = _grid_points(grid, section, local, step, profile, columns)
    rows, cols = ring.shape[0], z.shape[0]
    px = camera.project(probe)
    # Smooth quantities (quality, shading): computed on the projected nodes, interpolated
    # with the maps. Irradiance relative to a wall at the grid's radius, which every
    # strip of a run shares: a frame in a narrower stretch (its own section smaller)
    # sees its closer wall brighter, as the LEDs light it, not as an exposure change.
    sight, centre = np.empty((2, 0)), np.zeros(3)
    if with_quality:
        centre = local.translation_world_probe()
        normals = section.normals(ring)   # the section's (a reducer's cone left out)
        sight = np.stack([np.sum(ring * normals, axis=1), normals[:, :2] @ centre[:2]])
    fields = node_fields(px, rows, cols, step, with_quality, sight, ring[:, :2].copy(),
                         scale, z, centre, float(grid.radius_mm))
    return MapFields(*fields), z


def _resolution(map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Source pixels per grid step: the smaller of the two directions of the grid."""
    steps = []
    for axis in (0, 1):
        if map_x.shape[axis] >= 2:
            steps.append(np.hypot(np.gradient(map_x, axis=axis), np.gradient(map_y, axis=axis)))
    return np.minimum(*steps) if len(steps) == 2 else steps[0]


def unwrap(frame: np.ndarray, camera: CameraModel, pose: Pose, section: PipeSection,
           grid: WallGrid, *, step: int = 1) -> np.ndarray:
    """Resample ``frame`` (grey float32) onto the wall grid; masked nodes are NaN."""
    map_x, map_y = unwrap_maps(camera, pose, section, grid, step=step)
    return _remap(frame, map_x, map_y)


def _remap(frame: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    strip = cv2.remap(frame, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=np.nan)
    strip[map_x < 0] = np.nan
    return strip


@dataclass(frozen=True)
class Strip:
    """One frame unwrapped onto a grid: values, quality weight and LED shading.

    ``values`` is NaN and ``weight`` 0 wherever the node is masked.
    """

    values: np.ndarray
    weight: np.ndarray
    shading: np.ndarray


@dataclass(frozen=True)
class PackedMask:
    """A frame mask packed eight pixels to a byte along its rows
    (``numpy.packbits(mask, axis=1)``) and its width in pixels: how
    :func:`unwrap_with_quality` reads an occluder mask (:func:`pack_mask`)."""

    bits: np.ndarray
    width: int


def pack_mask(mask: np.ndarray | None) -> PackedMask:
    """``mask`` (boolean, the frame's shape; None: nothing occluded) packed once, for the
    many strips a run unwraps from frames of that mask."""
    hidden = np.zeros((0, 0), bool) if mask is None else np.asarray(mask, bool)
    return PackedMask(np.packbits(hidden, axis=1), hidden.shape[1])


def unwrap_with_quality(frame: np.ndarray, maps: UnwrapMaps, *, min_resolution: float = 0.5,
                        occluded: np.ndarray | PackedMask | None = None) -> Strip:
    """Strip with its quality weight and shading; poorly resolved or occluded nodes masked.

    Parameters
    ----------
    frame : numpy.ndarray
        Grey float32 frame.
    maps : UnwrapMaps
        From :func:`unwrap_maps` (``with_quality=True``) or :func:`polar_unwrap_maps`.
    min_resolution : float
        Nodes drawing on fewer source pixels per output pixel than this are masked
        (they would only be interpolated blur).
    occluded : numpy.ndarray or PackedMask, optional
        Boolean mask of the frame's pixels that never show the wall (mirror assembly,
        laser-holder arm, outside the lens' image circle); see :mod:`pipestitch.mosaic.occluders`.
        Packed by :func:`pack_mask` when many strips read it.
    """
    values = cv2.remap(frame, maps.map_x, maps.map_y, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    hidden = occluded if isinstance(occluded, PackedMask) else pack_mask(occluded)
    weight = mask_strip(values, maps.map_x, maps.map_y, maps.quality, float(min_resolution),
                        hidden.bits, hidden.width)
    return Strip(values, weight, maps.shading)


def local_contrast(values: np.ndarray, sigma_px: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """Value / local mean - 1 over the valid (finite) nodes, and the local data fraction.

    Removes illumination and exposure, keeps texture. Invalid nodes give 0.
    """
    contrast, support, _ = local_contrast_and_mean(values, sigma_px)
    return contrast, support


def local_contrast_and_mean(values: np.ndarray, sigma_px: float = 6.0
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`local_contrast` and the local mean it divides by (float32 each)."""
    filled, valid = fill_invalid(np.asarray(values, np.float32))
    support = gaussian_blur(valid, sigma_px, border=cv2.BORDER_REFLECT)
    local = gaussian_blur(filled, sigma_px, border=cv2.BORDER_REFLECT)
    contrast = contrast_of(filled, valid, support, local)   # makes ``local`` the mean
    return contrast, support, local


def strip_window_mm(camera: CameraModel, radius_mm: float, mm_per_px: float, *,
                    min_resolution: float = 0.5) -> tuple[float, float]:
    """Axial window (z0, z1) from the camera centre worth unwrapping in this pipe.

    From the field of view (how far behind the camera the wall still falls inside
    the image)
    to where a centred camera's resolution on the wall drops below
    ``min_resolution`` source pixels per output pixel, widened by a third of the
    radius each way for tilted and offset frames (their nodes outside the real
    window are masked by quality anyway).
    """
    z = np.linspace(-radius_mm, 6 * radius_mm, 701)
    th, zz = np.meshgrid(np.deg2rad([0.0, 90.0]), z, indexing="ij")
    px = camera.project(PipeSection(radius_mm).points(th.ravel(), zz.ravel())).reshape(2, -1, 2)
    inside = ((px[..., 0] >= 0) & (px[..., 0] <= camera.width - 1) & (px[..., 1] >= 0)
              & (px[..., 1] <= camera.height - 1))
    seen = inside.all(axis=0)
    step_px = np.linalg.norm(np.gradient(px[0], axis=0), axis=1) * mm_per_px / (z[1] - z[0])
    good = seen & (step_px >= min_resolution)
    if not good.any():
        raise ValueError(f"no part of a {2 * radius_mm:g} mm pipe is seen at "
                         f"{mm_per_px:g} mm/px with this camera")
    margin = radius_mm / 3
    return float(z[good].min() - margin), float(z[good].max() + margin)


def seen_window_mm(camera: CameraModel, views: Iterable[tuple[Pose, PipeSection]],
                   radius_mm: float, mm_per_px: float, window_mm: tuple[float, float], *,
                   min_resolution: float = 0.5, occluded: np.ndarray | None = None,
                   step: int = 16, margin_mm: float = 2.0) -> tuple[float, float]:
    """The part of ``window_mm`` that some frame of a run actually resolves.

    :func:`strip_window_mm` is a centred camera's window widened for any tilt and
    offset; at fine scales much of it is masked in every frame (too few source pixels
    per output pixel). Here the window shrinks to the axial range where at least one
    of ``views`` (each frame's pose and section) has a node inside the image, not
    ``occluded`` and at ``min_resolution`` or better (what :func:`unwrap_with_quality`
    masks by), checked every ``step``-th node of the ``mm_per_px`` grid and
    widened by one such step and ``margin_mm`` (the poses the refinement will still
    correct). The unwrapping, registration and stitching costs all scale with the
    window's length; nothing they would keep is cut. ``window_mm`` itself when no view
    resolves anything.
    """
    grid = WallGrid.window(radius_mm, mm_per_px, *window_mm)
    n_columns = _node_count(grid.n_cols, step)
    first, last = n_columns, -1   # the node columns some view resolves: first and last
    for pose, section in views:
        if first == 0 and last == n_columns - 1:
            break   # every column is resolved: no view can widen the window
        # Only the columns outside those already resolved can widen it: each view is
        # evaluated there alone, with the two resolved end columns as their neighbours
        # (a node's quality reads its neighbours along z); what it says of those two
        # (next to each other here) does not matter, they are resolved already.
        columns = (np.arange(n_columns) if last < 0 else
                   np.r_[np.arange(first + 1), np.arange(last, n_columns)])
        nodes, _ = _node_fields(camera, pose, section, grid, step, True, columns=columns)
        col, row = np.rint(nodes.map_x).astype(int), np.rint(nodes.map_y).astype(int)
        good = ((nodes.valid > 0) & (nodes.quality >= min_resolution) & (col >= 0)
                & (col < camera.width)
                & (row >= 0) & (row < camera.height))
        if occluded is not None:
            good[good] = ~occluded[row[good], col[good]]
        seen = np.flatnonzero(good.any(axis=0))
        if seen.size:
            first, last = min(first, int(columns[seen[0]])), max(last, int(columns[seen[-1]]))
    if last < 0:
        return window_mm
    lo, hi = _column_z(grid, step, np.array([first, last]))
    pad = step * mm_per_px + margin_mm
    return max(window_mm[0], float(lo) - pad), min(window_mm[1], float(hi) + pad)


def default_mm_per_px(camera: CameraModel, radius_mm: float) -> float:
    """Output scale: the axial resolution of a centred camera half a radius ahead.

    Rounded to 3 significant digits. Nearer the camera the wall is seen more finely
    (and the blend prefers it), further ahead more coarsely.
    """
    z = np.array([0.5 * radius_mm, 0.5 * radius_mm + 0.01])
    px = camera.project(np.stack([np.full(2, radius_mm), np.zeros(2), z], axis=1))
    mm = 0.01 / float(np.linalg.norm(px[1] - px[0]))
    return float(f"{mm:.3g}")


def polar_unwrap_maps(camera: CameraModel, radius_mm: float, grid: WallGrid) -> UnwrapMaps:
    """Prior-art baseline: polar unwrap about the image centre for a centred probe.

    Row i samples the ray at image azimuth theta_i about the geometric image centre
    and column j the image radius at which the lens sees a centred pipe's wall at
    z_j (so the baseline gets the same millimetre axes as ours). Tilt and offset of
    the probe, and the principal point's offset from the image centre, are ignored:
    that is what centralisation corrects. Quality is the resolution alone and the
    shading is that of a centred probe.
    """
    theta = np.deg2rad(grid.theta0_deg + np.arange(grid.n_rows) * grid.deg_per_px)
    z = grid.z0_mm + np.arange(grid.n_cols) * grid.mm_per_px_axial
    wall = np.stack([np.full_like(z, radius_mm), np.zeros_like(z), z], axis=1)
    px = camera.project(wall)
    principal = camera.project(np.array([[0.0, 0.0, 1.0]]))[0]
    rho = np.linalg.norm(px - principal, axis=1)
    centre = ((camera.width - 1) / 2, (camera.height - 1) / 2)
    map_x = centre[0] + rho[None, :] * np.cos(theta)[:, None]
    map_y = centre[1] + rho[None, :] * np.sin(theta)[:, None]
    ok = np.isfinite(rho)[None, :] & np.ones((grid.n_rows, 1), bool)
    distance = np.hypot(radius_mm, z)
    shading = np.broadcast_to((radius_mm / distance) ** 3, ok.shape)  # cos · (r/d)²
    quality = _resolution(np.where(ok, map_x, 0), np.where(ok, map_y, 0)) * (radius_mm / distance)
    return UnwrapMaps(np.where(ok, map_x, -1).astype(np.float32),
                      np.where(ok, map_y, -1).astype(np.float32),
                      np.where(ok, quality, 0).astype(np.float32),
                      np.where(ok, shading, 0).astype(np.float32))
