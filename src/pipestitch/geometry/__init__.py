"""Probe geometry: pose, rotations, pipe sections, intersections, clock positions, the
(theta, z) pixel grid on the wall (pure, vectorised maths; no I/O).

May import ``camera``. Must not import any stage, ``io``, ``pipeline`` or ``cli``.
"""

from __future__ import annotations

from pipestitch.geometry.body import BodyEnvelope
from pipestitch.geometry.cylinder import PipeSection, RadiusProfile, theta_z_from_points
from pipestitch.geometry.intersect import (
    laser_ring,
    plane_basis,
    ray_wall_distance,
    rays_to_wall,
)
from pipestitch.geometry.probe_pose import Pose
from pipestitch.geometry.rotations import rot_x, rot_y, rot_z
from pipestitch.geometry.wall_grid import WallGrid

__all__ = [
    "BodyEnvelope",
    "PipeSection",
    "Pose",
    "RadiusProfile",
    "WallGrid",
    "laser_ring",
    "plane_basis",
    "ray_wall_distance",
    "rays_to_wall",
    "rot_x",
    "rot_y",
    "rot_z",
    "theta_z_from_points",
]
