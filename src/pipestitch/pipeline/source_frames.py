"""The source frames of a point of the mosaic, for the review page.

A mosaic point (z, theta) is the point (theta - roll, z - z_frame) of a frame's own
wall grid (mosaic/blend.py, ``frame_grid``); it is projected into that frame with the
frame's pose (poses.csv) and section, as the unwrap does: the ellipse fitted to the
frame's ring where profile.csv has one (its semi-axes ``min_radius_mm`` and
``max_radius_mm``, the major axis at mosaic theta ``major_axis_theta_deg``, i.e. at
that angle less the frame's roll in the frame), else the circle of ``radius_mm``.
The picture returned is the LED frame in grey with the laser frame's ring drawn over
it in red and the point circled in yellow, reduced to at most ``MAX_WIDTH`` pixels:
how an inspector checks what the camera actually saw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.geometry.cylinder import PipeSection
from pipestitch.geometry.probe_pose import Pose
from pipestitch.geometry.wall_grid import WallGrid
from pipestitch.io.dataset import Dataset, open_dataset
from pipestitch.mosaic.unwrap import unwrap_maps

__all__ = ["FramePoses", "SourceFrames"]

MAX_WIDTH = 640
POSE_COLUMNS = ("alpha_deg", "beta_deg", "dx_mm", "dy_mm", "z_mm", "roll_deg", "radius_mm")
SECTION_COLUMNS = ("ovality", "min_radius_mm", "max_radius_mm", "major_axis_theta_deg")
ROLL, RADIUS = POSE_COLUMNS.index("roll_deg"), POSE_COLUMNS.index("radius_mm")


def _finite_row(row: dict[str, str], columns: tuple[str, ...]) -> tuple[int, tuple[float, ...]]:
    """(frame, the values of ``columns``); ValueError when one is missing or not finite."""
    try:
        frame, values = int(row["frame"]), tuple(float(row[c]) for c in columns)
    except (KeyError, TypeError, ValueError):
        raise ValueError("not a finite row") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError("not a finite row")
    return frame, values


def _fitted_sections(profile: list[dict[str, str]],
                     poses: dict[int, tuple[float, ...]]) -> dict[int, PipeSection]:
    """Per frame with a pose, the ellipse profile.csv gives (in the frame's own angles)."""
    sections = {}
    for row in profile:
        try:
            frame, (_, low, high, axis_deg) = _finite_row(row, SECTION_COLUMNS)
            if frame in poses:
                sections[frame] = PipeSection(high, low,
                                              math.radians(axis_deg - poses[frame][ROLL]))
        except ValueError:     # no ellipse fitted (ovality nan), or not a valid one
            continue
    return sections


@dataclass(frozen=True)
class FramePoses:
    """Per frame (poses.csv) the pose the mosaic used: ``values[frame]`` in the order of
    ``POSE_COLUMNS``; ``sections[frame]`` the ellipse fitted to its ring, where there is
    one (profile.csv)."""

    values: dict[int, tuple[float, ...]]
    sections: dict[int, PipeSection] = field(default_factory=dict)

    @classmethod
    def from_rows(cls, rows: list[dict[str, str]],
                  profile: list[dict[str, str]] | None = None) -> FramePoses:
        """From poses.csv's rows (frames without a finite pose left out) and
        profile.csv's (frames without a fitted ellipse get the circle)."""
        values = {}
        for row in rows:
            try:
                frame, pose = _finite_row(row, POSE_COLUMNS)
            except ValueError:
                continue
            values[frame] = pose
        return cls(values, _fitted_sections(profile or [], values))

    def section(self, frame: int) -> PipeSection:
        """The section ``frame`` was unwrapped with: its fitted ellipse, else its circle.
        KeyError when the frame has no pose."""
        circle = PipeSection.circle(2 * self.values[frame][RADIUS])
        return self.sections.get(frame, circle)


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        image = cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2GRAY)
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    return image


class SourceFrames:
    """The dataset's frames, opened when first asked for (the dataset recorded in
    standards.json may have moved: :attr:`problem` then says why there are none)."""

    def __init__(self, root: str | Path | None, poses: FramePoses, *, deg_per_px: float,
                 mm_per_px: float) -> None:
        self.root, self.poses = (Path(root) if root else None), poses
        self.deg_per_px, self.mm_per_px = deg_per_px, mm_per_px
        self._dataset: Dataset | None = None
        self.problem = "" if self.root is not None else "the run recorded no dataset"
        if self.root is not None and not (self.root / "probe.toml").is_file():
            self.problem = f"{self.root}: no dataset there (probe.toml missing)"

    @property
    def available(self) -> bool:
        """True when the frames can be shown."""
        return not self.problem

    def _opened(self) -> Dataset:
        if self._dataset is None:
            try:
                self._dataset = open_dataset(self.root)
            except DatasetError as exc:
                self.problem = str(exc)
                raise
        return self._dataset

    def point_in_frame(self, frame: int, z_mm: float, theta_deg: float) -> tuple[float, float]:
        """Pixel (col, row) of mosaic point (z, theta) in ``frame`` (NaN: not seen)."""
        alpha, beta, dx, dy, z_frame, roll, radius = self.poses.values[frame]
        grid = WallGrid(radius_mm=radius, deg_per_px=self.deg_per_px,
                        mm_per_px_axial=self.mm_per_px, z0_mm=z_mm - z_frame, n_cols=1,
                        theta0_deg=theta_deg - roll)
        map_x, map_y = unwrap_maps(self._opened().config.camera_model(),
                                   Pose.from_degrees(alpha, beta, dx, dy),
                                   self.poses.section(frame), grid)
        x, y = float(map_x[0, 0]), float(map_y[0, 0])
        return (x, y) if x >= 0 and y >= 0 else (math.nan, math.nan)

    def picture(self, frame: int, z_mm: float, theta_deg: float) -> bytes:
        """The LED frame with its laser ring and the point marked, as JPEG bytes.

        Raises
        ------
        KeyError
            ``frame`` has no pose.
        DatasetError
            The dataset or the frame cannot be read (naming the file).
        """
        if frame not in self.poses.values:
            raise KeyError(frame)
        dataset = self._opened()
        led = _gray(dataset.read_led(frame))
        laser = _gray(dataset.read_laser(frame))
        picture = cv2.cvtColor(led, cv2.COLOR_GRAY2BGR)
        ring = laser > max(40, int(np.percentile(laser, 99.5)) // 2)
        picture[ring] = (40, 40, 255)
        x, y = self.point_in_frame(frame, z_mm, theta_deg)
        if math.isfinite(x):
            radius = max(6, led.shape[1] // 60)
            cv2.circle(picture, (round(x), round(y)), radius, (0, 255, 255), max(2, radius // 4))
        scale = min(1.0, MAX_WIDTH / picture.shape[1])
        if scale < 1.0:
            picture = cv2.resize(picture, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 85])
        if not ok:
            raise DatasetError(self.root, f"frame {frame:05d}: could not encode the picture")
        return data.tobytes()
