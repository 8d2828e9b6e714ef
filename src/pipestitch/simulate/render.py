"""Rendering laser and LED frames by ray tracing every pixel to the pipe wall.

Each pixel's ray (unprojected once per camera) is moved into the world by the
frame's pose and intersected with the wall; the hit point gives

* the LED frame: the wall texture sampled with ``cv2.remap`` from a mip pyramid
  chosen by the pixel's footprint on the wall (trilinear filtering, so the far
  wall near the image centre does not alias), lit by LEDs at the camera
  (cos(incidence)/distance²), with lens vignetting, shot and read noise and
  quantisation;
* the laser frame: the laser sheet's Gaussian profile evaluated at the hit point's
  distance from the laser plane, so the ring's image width follows from the
  geometry, on a dark background with speckle, noise and optional glints and
  partial rings.

The mirror assembly (a disc around the optical axis), the laser holder arm (a
radial sector) and the lens' image circle are occluded in both frames. The
renderer knows the true pose and geometry; it shares the camera and geometry
modules with the estimators but none of their estimation code.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipestitch.camera import CameraModel, pixel_grid
from pipestitch.geometry import PipeSection, Pose, RadiusProfile, WallGrid, ray_wall_distance
from pipestitch.simulate._remap import remap_points, remap_wrap
from pipestitch.simulate.optics import Optics

__all__ = ["Optics", "Renderer", "WallTexture"]


@dataclass(frozen=True, kw_only=True)
class WallTexture:
    """Unrolled wall albedo on its grid (in the world frame: theta and z of the pipe).

    Parameters
    ----------
    albedo : numpy.ndarray, shape grid.shape
        Albedo of each grid node (rows: theta, columns: z).
    grid : WallGrid
        Its grid.

    Raises
    ------
    ValueError
        When ``albedo`` is not an image of ``grid``'s shape.
    """

    albedo: np.ndarray
    grid: WallGrid

    def __post_init__(self) -> None:
        if np.shape(self.albedo) != self.grid.shape:
            raise ValueError(f"WallTexture: albedo of shape {np.shape(self.albedo)} on a grid "
                             f"of shape {self.grid.shape} (rows, columns)")


class Renderer:
    """Renders frame pairs of one camera in one pipe over one wall texture.

    Parameters
    ----------
    camera : CameraModel
        Camera model (defines the image size).
    section : PipeSection
        Pipe cross-section (in the world frame).
    wall : WallTexture
        The wall's albedo.
    plane_distance_mm : float
        Laser plane distance d.
    optics : Optics
        Optics and sensor parameters.
    plane_normal : array_like, optional
        Unit normal of the laser plane in the probe frame (default +z, SPEC).
    profile : RadiusProfile, optional
        The section's scale along world z (a reducer); default the same everywhere.
    """

    def __init__(self, camera: CameraModel, section: PipeSection, wall: WallTexture,
                 plane_distance_mm: float, optics: Optics | None = None,
                 plane_normal: np.ndarray | None = None,
                 profile: RadiusProfile | None = None) -> None:
        self.camera = camera
        self.section = section
        self.profile = profile
        self.wall = wall
        self.optics = optics or Optics()
        self.plane_distance_mm = float(plane_distance_mm)
        normal = np.array([0.0, 0.0, 1.0]) if plane_normal is None else np.asarray(plane_normal)
        self.plane_normal = normal / np.linalg.norm(normal)
        shape = (camera.height, camera.width)
        rays = camera.unproject(pixel_grid(camera.width, camera.height))
        self._rays = np.nan_to_num(rays).astype(np.float32).reshape(*shape, 3)
        self._incidence = np.arccos(np.clip(np.nan_to_num(rays[:, 2], nan=-1.0), -1, 1))
        self._incidence = self._incidence.reshape(shape).astype(np.float32)
        self.visibility = self._visibility(rays.reshape(*shape, 3))
        self.occluder_light = self._occluder_light()
        self._pyramid = self._build_pyramid(wall.albedo.astype(np.float32))
        self._visible_index = np.flatnonzero(self.visibility.ravel() > 0)
        self._rays_visible = self._rays.reshape(-1, 3)[self._visible_index]
        self._ray_normal = self._rays_visible @ self.plane_normal.astype(np.float32)

    # --- static parts -----------------------------------------------------------------
    def _visibility(self, rays: np.ndarray) -> np.ndarray:
        """Fraction of each pixel not occluded by lens rim, mirror assembly or arm."""
        o = self.optics
        inc_deg = np.rad2deg(self._incidence)
        pixel_deg = np.rad2deg(1.0 / max(self.camera.width, self.camera.height)) * 4
        lens = np.clip((o.fov_deg / 2 - inc_deg) / pixel_deg + 0.5, 0, 1)
        mirror_deg = np.rad2deg(np.arctan2(o.mirror_radius_mm, self.plane_distance_mm))
        mirror = np.clip((inc_deg - mirror_deg) / pixel_deg + 0.5, 0, 1)
        azimuth = np.rad2deg(np.arctan2(rays[..., 1], rays[..., 0]))
        off = np.abs((azimuth - o.arm_azimuth_deg + 180) % 360 - 180)
        # The arm is a bar of constant width: its angular width in the image is
        # constant in azimuth; soften its edge by about one pixel at the ring.
        arm = np.clip((off - o.arm_width_deg / 2) / 0.15 + 0.5, 0, 1)
        arm = np.where(inc_deg > mirror_deg, arm, 1.0)
        vis = lens * mirror * arm
        vis[~np.isfinite(rays[..., 2])] = 0
        return vis.astype(np.float32)

    def _occluder_light(self) -> np.ndarray | None:
        """What the arm and the mirror assembly show in an LED frame (None: nothing).

        They sit where the image circle shows something but not the wall; a metal part
        lit by the LEDs is brighter towards its far end, where the wall is darker.
        """
        o = self.optics
        if o.occluder_level <= 0:
            return None
        inc_deg = np.rad2deg(self._incidence)
        pixel_deg = np.rad2deg(1.0 / max(self.camera.width, self.camera.height)) * 4
        lens = np.clip((o.fov_deg / 2 - inc_deg) / pixel_deg + 0.5, 0, 1)
        outward = 1.0 + 0.6 * np.clip(inc_deg / (o.fov_deg / 2), 0, 1)
        hidden = lens * (1.0 - self.visibility / np.maximum(lens, 1e-6))
        return (o.occluder_level * outward * np.clip(hidden, 0, 1)).astype(np.float32)

    def _build_pyramid(self, albedo: np.ndarray) -> list[np.ndarray]:
        levels = [albedo]
        while min(levels[-1].shape) > 64 and len(levels) < 7:
            h, w = levels[-1].shape
            levels.append(cv2.resize(levels[-1], ((w + 1) // 2, (h + 1) // 2),
                                     interpolation=cv2.INTER_AREA))
        return levels

    # --- per frame ----------------------------------------------------------------------
    def trace(self, pose: Pose) -> dict[str, np.ndarray]:
        """Trace every visible pixel to the wall.

        Returns
        -------
        dict
            ``row``/``col``: texture coordinates (float32 maps), ``plane_mm``:
            signed distance of the hit point from the laser plane, ``light``: LED
            irradiance factor, ``hit``: bool mask of pixels that reach the textured wall.
        """
        origin, dirs, s = self._cast(pose)
        hit = origin + s[:, None] * dirs
        row, col = self._texture_coords(hit)
        normals = self.section.normals(hit)
        cos_inc = np.abs(normals[:, 0] * dirs[:, 0] + normals[:, 1] * dirs[:, 1])
        values = {
            "row": row,
            "col": col,
            "plane_mm": s * self._ray_normal - self.plane_distance_mm,
            "light": cos_inc * (self.section.mean_radius_mm / s) ** 2,
        }
        out = {key: self._full(v, self._visible_index, -10.0) for key, v in values.items()}
        n_cols = self.wall.albedo.shape[1]
        out["hit"] = (out["col"] >= 0) & (out["col"] <= n_cols - 1) & (out["light"] > 0)
        return out

    def _cast(self, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera centre, world ray directions and wall distance of every visible pixel."""
        origin = pose.translation_world_probe().astype(np.float32)
        dirs = self._rays_visible @ pose.rotation_world_probe().T.astype(np.float32)
        return origin, dirs, ray_wall_distance(origin, dirs, self.section, self.profile)

    def _texture_coords(self, hit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) of world wall points in the wall texture."""
        g = self.wall.grid
        theta_deg = (np.rad2deg(np.arctan2(hit[:, 1], hit[:, 0])) - g.theta0_deg) % 360
        return theta_deg / g.deg_per_px, (hit[:, 2] - g.z0_mm) / g.mm_per_px_axial

    def _full(self, values: np.ndarray, index: np.ndarray, fill: float) -> np.ndarray:
        """An image of the sensor's shape with ``values`` at flat ``index``, ``fill`` elsewhere."""
        full = np.full(self._rays.shape[:2], fill, np.float32)
        full.ravel()[index] = np.nan_to_num(values, nan=fill)
        return full

    def sample_albedo(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Albedo at texture coordinates, filtered by each pixel's footprint (mipmap)."""
        n_rows = self.wall.albedo.shape[0]
        d_row_y, d_row_x = np.gradient(row)
        d_row_y = np.minimum(np.abs(d_row_y), n_rows - np.abs(d_row_y))  # theta wraps
        d_row_x = np.minimum(np.abs(d_row_x), n_rows - np.abs(d_row_x))
        d_col_y, d_col_x = np.gradient(col)
        footprint = np.maximum(np.hypot(d_row_x, d_col_x), np.hypot(d_row_y, d_col_y))
        level = np.clip(np.log2(np.maximum(footprint, 1e-3)), 0, len(self._pyramid) - 1)
        out = np.zeros(row.shape, np.float32)
        for i, tex in enumerate(self._pyramid):
            weight = np.clip(1 - np.abs(level - i), 0, 1)
            if not np.any(weight > 0):
                continue
            sy = tex.shape[0] / n_rows
            sx = tex.shape[1] / self.wall.albedo.shape[1]
            map_x = (col + 0.5) * sx - 0.5
            map_y = (row + 0.5) * sy - 0.5
            sample = remap_wrap(tex, map_x, map_y)
            out += weight * sample
        return out

    def _sensor(self, signal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Shot + read noise and quantisation of a signal in [0, 1]."""
        o = self.optics
        electrons = np.clip(signal, 0, None) * o.full_well_e
        noisy = electrons + np.sqrt(electrons) * rng.standard_normal(signal.shape, np.float32)
        noisy = noisy / o.full_well_e + o.read_noise * rng.standard_normal(signal.shape,
                                                                             np.float32)
        full = 255 if o.bit_depth == 8 else 65535
        dtype = np.uint8 if o.bit_depth == 8 else np.uint16
        return np.clip(np.rint(noisy * full), 0, full).astype(dtype)

    def _colourise(self, grey: np.ndarray, bgr_gain: tuple[float, float, float],
                   rng: np.random.Generator) -> np.ndarray:
        if not self.optics.colour:
            return self._sensor(grey, rng)
        return np.dstack([self._sensor(grey * g, rng) for g in bgr_gain])

    def _traced_albedo(self, pose: Pose) -> tuple[dict[str, np.ndarray], np.ndarray]:
        tr = self.trace(pose)
        return tr, np.where(tr["hit"], self.sample_albedo(tr["row"], tr["col"]), 0.0)

    def render_laser(self, pose: Pose, rng: np.random.Generator) -> np.ndarray:
        """Render the laser frame alone (laser-only datasets, pose benchmarks).

        Same physics as the laser frame of :meth:`render_pair`, but the wall texture
        is sampled only where the laser sheet lights it (within 6 sigma of the plane),
        at full texture resolution: near the ring a pixel covers about one texel, so
        the mip pyramid is not needed there. About 3x faster.
        """
        origin, dirs, s = self._cast(pose)
        plane = s * self._ray_normal - self.plane_distance_mm
        near = np.flatnonzero(np.abs(np.nan_to_num(plane, nan=1e9))
                              < 6 * self.optics.laser_sigma_mm)
        row, col = self._texture_coords(origin + s[near, None] * dirs[near])
        inside = (col >= 0) & (col <= self.wall.albedo.shape[1] - 1)
        lit = self._visible_index[near[inside]]
        albedo = self._full(remap_points(self._pyramid[0], col, row)[inside], lit, 0.0)
        tr = {"plane_mm": self._full(plane, self._visible_index, -10.0),
              "hit": self._full(np.ones(lit.size), lit, 0.0) > 0}
        laser = self._laser_signal(tr, albedo, rng)
        return self._colourise(laser * self.visibility, (0.08, 0.12, 1.0), rng)

    def render_pair(self, pose: Pose, rng: np.random.Generator, *, exposure: float = 1.0,
                    led_pose: Pose | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Render the (laser, LED) frames of one pair at ``pose`` (the LED frame at
        ``exposure`` times the optics' ``led_gain``, and at ``led_pose`` where given: the
        probe moved between the two)."""
        tr, albedo = self._traced_albedo(pose)
        laser = self._laser_signal(tr, albedo, rng) * self.visibility
        if led_pose is not None:
            tr, albedo = self._traced_albedo(led_pose)
        o = self.optics
        vignette = 1 - o.vignetting * (self._incidence / np.deg2rad(o.fov_deg / 2)) ** 2
        led = o.led_gain * exposure * albedo * tr["light"] * vignette * self.visibility
        if self.occluder_light is not None:
            led = led + self.occluder_light
        return (self._colourise(laser, (0.08, 0.12, 1.0), rng),
                self._colourise(led, (0.85, 1.0, 1.05), rng))

    def _laser_signal(self, tr: dict[str, np.ndarray], albedo: np.ndarray,
                      rng: np.random.Generator) -> np.ndarray:
        o = self.optics
        sheet = np.exp(-0.5 * (tr["plane_mm"] / o.laser_sigma_mm) ** 2)
        # Diffuse wall: the laser returns in proportion to the same reflectance the LEDs
        # see (laser_peak is the brightness on a wall of albedo 0.6).
        sheet *= np.where(tr["hit"], albedo / 0.6, 0.0)
        speckle = 1 + o.speckle * rng.standard_normal(sheet.shape, np.float32)
        signal = o.laser_peak * sheet * np.clip(speckle, 0, None) + o.laser_background
        if o.partial_ring_deg > 0:
            signal = np.where(self._sector(rng.uniform(0, 360), o.partial_ring_deg),
                              o.laser_background, signal)
        for _ in range(o.glints):
            signal = signal + self._glint(rng)
        return signal

    def _sector(self, centre_deg: float, width_deg: float) -> np.ndarray:
        rays = self._rays
        azimuth = np.rad2deg(np.arctan2(rays[..., 1], rays[..., 0]))
        return np.abs((azimuth - centre_deg + 180) % 360 - 180) < width_deg / 2

    def _glint(self, rng: np.random.Generator) -> np.ndarray:
        """A specular blob: a bright saturated Gaussian spot somewhere on the wall image."""
        h, w = self._rays.shape[:2]
        while True:
            col, row = rng.uniform(0, w), rng.uniform(0, h)
            if self.visibility[int(row), int(col)] > 0.5:
                break
        sigma = rng.uniform(2.0, 8.0) * max(h, w) / 2448
        x0, x1 = int(max(col - 5 * sigma, 0)), int(min(col + 5 * sigma + 1, w))
        y0, y1 = int(max(row - 5 * sigma, 0)), int(min(row + 5 * sigma + 1, h))
        blob = np.zeros((h, w), np.float32)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        blob[y0:y1, x0:x1] = 1.5 * np.exp(-((xx - col) ** 2 + (yy - row) ** 2) / (2 * sigma**2))
        return blob
