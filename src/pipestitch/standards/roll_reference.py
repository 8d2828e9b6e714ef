"""The roll reference that fixes 12 o'clock on the mosaic (clock maths: geometry.clock).

Convention (docs/conventions.md, "Clock positions"): 12 = crown, 3 = right, 6 = invert,
9 = left, clockwise as seen looking in the direction of survey (+z). In a pipe frame
whose +y points down (gravity), theta = atan2(y, x) grows from 3 o'clock (+x) towards
6 o'clock (+y), i.e. clockwise for that viewer, and the crown is at theta = 270 deg.

The mosaic's theta is relative (the laser cannot see roll): a :class:`RollReference`
says at which mosaic theta the crown lies and where that came from.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from pipestitch.geometry.clock import CROWN_THETA_GRAVITY_DEG, clock_hhmm, clock_hour

__all__ = ["CROWN_THETA_GRAVITY_DEG", "REFERENCE_SOURCES", "RollReference", "clock_hhmm",
           "clock_hour", "crown_from_imu", "crown_from_invert", "imu_roll_offset",
           "relative_reference", "user_reference"]

REFERENCE_SOURCES = ("imu", "invert-detected", "user (--crown-deg)", "relative")


@dataclass(frozen=True)
class RollReference:
    """Where 12 o'clock is on the mosaic.

    Attributes
    ----------
    crown_theta_deg : float
        Mosaic theta (deg, [0, 360)) of the crown (12 o'clock).
    source : str
        One of ``REFERENCE_SOURCES``.
    detail : str
        How it was obtained (for the report and the exported headers).
    """

    crown_theta_deg: float
    source: str
    detail: str = ""

    def __post_init__(self) -> None:
        if self.source not in REFERENCE_SOURCES:
            raise ValueError(f"source: expected one of {REFERENCE_SOURCES}, got {self.source!r}")
        if not math.isfinite(self.crown_theta_deg):
            raise ValueError("crown_theta_deg: expected a finite angle, "
                             f"got {self.crown_theta_deg}")
        object.__setattr__(self, "crown_theta_deg", float(self.crown_theta_deg) % 360.0)

    def to_gravity(self, theta_deg: float) -> float:
        """Mosaic theta -> theta in the gravity frame (+y down, crown at 270 deg)."""
        return (theta_deg - self.crown_theta_deg + CROWN_THETA_GRAVITY_DEG) % 360.0


def relative_reference() -> RollReference:
    """No reference: 12 o'clock is the image up of the mosaic's roll reference frame."""
    return RollReference(CROWN_THETA_GRAVITY_DEG, "relative",
                         "12 o'clock = image up of the mosaic's first frame (theta 270 deg)")


def user_reference(crown_deg: float) -> RollReference:
    """The crown at mosaic theta ``crown_deg`` (``--crown-deg``)."""
    return RollReference(crown_deg, "user (--crown-deg)",
                         f"crown at mosaic theta {crown_deg:g} deg")


def _circular_mean_deg(angles_deg: np.ndarray) -> tuple[float, float]:
    """Circular mean and circular standard deviation (deg)."""
    a = np.deg2rad(angles_deg)
    c, s = float(np.mean(np.cos(a))), float(np.mean(np.sin(a)))
    r = min(1.0, math.hypot(c, s))
    spread = math.degrees(math.sqrt(-2 * math.log(r))) if r > 0 else 180.0
    return math.degrees(math.atan2(s, c)) % 360.0, spread


def crown_from_imu(mosaic_roll_deg: Mapping[int, float],
                   imu_roll_deg: Mapping[int, float]) -> RollReference | None:
    """Crown from a gravity roll per frame.

    ``imu_roll_deg`` is each frame's roll (SPEC's gamma) in a pipe frame whose +y points
    down; ``mosaic_roll_deg`` the same frames' relative roll (poses.csv). A wall point at
    mosaic theta t is at gravity theta t - roll_mosaic + roll_imu, the same offset c for
    every frame, so the crown (gravity theta 270) is at mosaic theta 270 - c. c is the
    circular mean over the frames both know.

    Returns None when no frame has both.
    """
    found = imu_roll_offset(mosaic_roll_deg, imu_roll_deg)
    if found is None:
        return None
    c, spread, count = found
    return RollReference((CROWN_THETA_GRAVITY_DEG - c) % 360.0, "imu",
                         f"imu.csv roll over {count} frames (spread {spread:.2f} deg)")


def imu_roll_offset(mosaic_roll_deg: Mapping[int, float], imu_roll_deg: Mapping[int, float]
                    ) -> tuple[float, float, int] | None:
    """The offset c (deg, in (-180, 180]) that turns the frames' relative roll into the
    IMU's (gravity) roll, gamma = roll + c: the circular mean of ``imu - roll`` over the
    frames both know; with its circular spread and the number of frames. None when no
    frame has both."""
    common = sorted(k for k in mosaic_roll_deg if k in imu_roll_deg
                    and math.isfinite(mosaic_roll_deg[k]) and math.isfinite(imu_roll_deg[k]))
    if not common:
        return None
    offsets = np.array([imu_roll_deg[k] - mosaic_roll_deg[k] for k in common])
    c, spread = _circular_mean_deg(offsets)
    return (c - 360.0 if c > 180.0 else c), spread, len(common)


def crown_from_invert(invert_theta_deg: float, detail: str = "") -> RollReference:
    """Crown opposite the detected invert."""
    return RollReference(invert_theta_deg + 180.0, "invert-detected", detail)
