"""The rigid probe body and whether a pose keeps it inside the pipe."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipestitch.geometry.cylinder import PipeSection
from pipestitch.geometry.probe_pose import Pose

__all__ = ["BodyEnvelope"]


@dataclass(frozen=True)
class BodyEnvelope:
    """The probe body: a cylinder from the camera centre back to ``-length_mm``."""

    length_mm: float = 145.0
    diameter_mm: float = 45.0

    def rim_points(self, n: int = 72) -> np.ndarray:
        """Probe-frame points on the front and rear rims of the body (2n, 3)."""
        phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
        ring = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1) * self.diameter_mm / 2
        rear = ring - [0.0, 0.0, self.length_mm]
        return np.concatenate([ring, rear])

    def clearance_mm(self, pose: Pose, section: PipeSection) -> float:
        """Smallest radial gap between the body and the wall (< 0: it does not fit)."""
        return float(np.min(section.clearance_mm(pose.to_world(self.rim_points()))))
