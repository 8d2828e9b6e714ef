"""Synthetic checkerboard views: a known board seen through a known camera model.

For tests and demonstrations of the camera calibration: every pixel is
supersampled (n × n rays through the camera's ``unproject``), each ray is
intersected with the board plane, and the checker colour at the hit point is
averaged, so edges are anti-aliased as in a real image and corner detection
reaches sub-pixel accuracy. The board has a white margin of one square around the
pattern; the background is mid grey.
"""

from __future__ import annotations

import numpy as np

from pipestitch.calibrate.checkerboard import Board
from pipestitch.camera import CameraModel, pixel_grid
from pipestitch.geometry import rot_x, rot_y, rot_z

__all__ = ["BoardRenderer", "board_pose"]

_BLACK, _WHITE, _BACKGROUND = 30.0, 225.0, 128.0


def board_pose(board: Board, *, distance_mm: float, off_axis_deg: float, azimuth_deg: float,
               tilt_deg: tuple[float, float] = (0.0, 0.0), spin_deg: float = 0.0
               ) -> tuple[np.ndarray, np.ndarray]:
    """A board pose (``R_probe_board``, ``t``) with its centre at a given direction.

    The board's centre is ``distance_mm`` from the camera, ``off_axis_deg`` from the
    optical axis at image azimuth ``azimuth_deg``; the board faces the camera, then
    is tilted by ``tilt_deg`` (about its x and y axes) and spun about its normal.
    """
    off, az = np.deg2rad(off_axis_deg), np.deg2rad(azimuth_deg)
    direction = np.array([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az), np.cos(off)])
    # Face the camera: board z along the viewing direction (board normal towards the lens).
    z = direction
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    facing = np.stack([x, np.cross(z, x), z], axis=1)
    rot = (facing @ rot_x(np.deg2rad(tilt_deg[0])) @ rot_y(np.deg2rad(tilt_deg[1]))
           @ rot_z(np.deg2rad(spin_deg)))
    centre_board = np.array([(board.cols - 1) / 2, (board.rows - 1) / 2, 0.0]) * board.square_mm
    return rot, distance_mm * direction - rot @ centre_board


def _checker(xy: np.ndarray, board: Board) -> np.ndarray:
    sq = board.square_mm
    i, j = np.floor(xy[:, 0] / sq), np.floor(xy[:, 1] / sq)
    inside = (i >= -1) & (i < board.cols) & (j >= -1) & (j < board.rows)
    margin = (i >= -2) & (i < board.cols + 1) & (j >= -2) & (j < board.rows + 1)
    value = np.where((i + j) % 2 == 0, _BLACK, _WHITE)
    return np.where(inside, value, np.where(margin, _WHITE, _BACKGROUND))


class BoardRenderer:
    """Renders boards through one camera; the supersampled rays are computed once.

    Parameters
    ----------
    camera : CameraModel
        The (true) camera model.
    supersample : int
        Rays per pixel along each axis.
    """

    def __init__(self, camera: CameraModel, *, supersample: int = 3) -> None:
        self.camera = camera
        base = pixel_grid(camera.width, camera.height)
        offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
        self._rays = [camera.unproject(base + [dx, dy]).astype(np.float32)
                      for dy in offsets for dx in offsets]

    def render(self, board: Board, rotation: np.ndarray, translation: np.ndarray, *,
               noise: float = 0.0, seed: int = 0) -> np.ndarray:
        """The board at pose (``rotation``, ``translation``) as an 8-bit grey image.

        ``rotation``, ``translation``: ``R_probe_board`` (3, 3) and ``t`` (3,) in mm
        (board point b is at R·b + t); ``noise``: Gaussian noise in grey levels.
        """
        normal = rotation[:, 2]
        total = np.zeros(len(self._rays[0]))
        for rays in self._rays:
            with np.errstate(invalid="ignore", divide="ignore"):
                s = (normal @ translation) / (rays @ normal)
            xy = (rays * s[:, None] - translation) @ rotation[:, :2]
            value = _checker(np.nan_to_num(xy, nan=1e9), board)
            total += np.where(np.isfinite(s) & (s > 0), value, _BACKGROUND)
        img = total / len(self._rays)
        if noise > 0:
            img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
        shape = (self.camera.height, self.camera.width)
        return np.clip(np.round(img), 0, 255).astype(np.uint8).reshape(shape)
