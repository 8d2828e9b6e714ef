"""Probe trajectories for the simulator.

``wandering_poses`` moves a rigid probe body (a cylinder of the probe.toml length
and diameter, behind the camera centre) along the pipe with a slowly wandering
tilt and offset that always keeps the body inside the pipe, plus a slowly varying
roll. The wander is generated for the body's front and rear axis points, which is
how a real probe moves (each end slides on the wall), and the pose is derived from
them. ``table1_poses`` draws independent poses as the reference design's evaluation.
"""

from __future__ import annotations

import numpy as np

from pipestitch.geometry import BodyEnvelope, PipeSection, Pose

__all__ = ["odometer_readings", "table1_poses", "wandering_poses"]


def _smooth_walk(z: np.ndarray, rng: np.random.Generator, wavelengths_mm: tuple[float, float],
                 n_terms: int = 4) -> np.ndarray:
    """A smooth 2-D random curve over z: a sum of random sinusoids, max norm 1."""
    lam = rng.uniform(*wavelengths_mm, size=(n_terms, 1))
    phase = rng.uniform(0, 2 * np.pi, size=(n_terms, 2))
    amp = rng.uniform(0.3, 1.0, size=(n_terms, 1))
    arg = 2 * np.pi * z[None, :] / lam
    xy = np.stack([np.sum(amp * np.sin(arg + phase[:, :1]), 0),
                   np.sum(amp * np.sin(arg + phase[:, 1:]), 0)], axis=1)
    return xy / max(np.max(np.linalg.norm(xy, axis=1)), 1e-12)


def _pose_from_ends(front: np.ndarray, rear: np.ndarray, length_mm: float, roll: float,
                    z_mm: float) -> Pose:
    """Pose whose camera centre is at ``front`` and whose axis passes over ``rear``."""
    axis = np.array([front[0] - rear[0], front[1] - rear[1], length_mm])
    axis /= np.linalg.norm(axis)
    # Probe z axis in the world is Rx(alpha)·Ry(beta)·e3 = (sin b, -sin a cos b, cos a cos b).
    beta = np.arcsin(axis[0])
    alpha = np.arctan2(-axis[1], axis[2])
    return Pose(alpha, beta, float(front[0]), float(front[1]), roll, z_mm)


def wandering_poses(n_pairs: int, section: PipeSection, body: BodyEnvelope,
                    rng: np.random.Generator, *, step_mm: float = 5.0,
                    step_jitter_mm: float = 0.4, wander: float = 0.8,
                    roll_amplitude_deg: float = 6.0, z_start_mm: float = 0.0,
                    margin_mm: float = 0.3) -> list[Pose]:
    """A run of ``n_pairs`` poses advancing ~``step_mm`` per pair.

    Parameters
    ----------
    n_pairs : int
        Number of poses.
    section : PipeSection
        Pipe cross-section (circular or oval).
    body : BodyEnvelope
        Probe body that must stay inside the pipe.
    rng : numpy.random.Generator
        Random source.
    step_mm, step_jitter_mm : float
        Mean axial advance per pair and its standard deviation.
    wander : float
        Fraction (0..1) of the free radial play the body's ends use.
    roll_amplitude_deg : float
        Amplitude of the slow roll about the pipe axis.
    z_start_mm : float
        Axial position of the first pose.
    margin_mm : float
        Smallest allowed gap between body and wall.
    """
    steps = np.clip(rng.normal(step_mm, step_jitter_mm, n_pairs), 0.2 * step_mm, None)
    z = z_start_mm + np.concatenate([[0.0], np.cumsum(steps[1:])])
    play = min(section.a_mm, section.b_mm) - body.diameter_mm / 2 - margin_mm
    if play <= 0:
        raise ValueError(f"probe body of {body.diameter_mm} mm does not fit the pipe")
    front = _smooth_walk(z, rng, (120.0, 500.0)) * play * wander
    rear = _smooth_walk(z, rng, (120.0, 500.0)) * play * wander
    roll = np.deg2rad(roll_amplitude_deg) * np.sin(
        2 * np.pi * z / rng.uniform(300, 900) + rng.uniform(0, 2 * np.pi))
    poses = []
    for i in range(n_pairs):
        shrink = 1.0
        while True:  # the rims tilt outwards a little: shrink until the body clears the wall
            pose = _pose_from_ends(front[i] * shrink, rear[i] * shrink, body.length_mm,
                                   float(roll[i]), float(z[i]))
            if body.clearance_mm(pose, section) >= margin_mm or shrink < 0.05:
                break
            shrink *= 0.97
        poses.append(pose)
    return poses


def table1_poses(n: int, radius_mm: float, plane_distance_mm: float,
                 rng: np.random.Generator, *, body_length_mm: float = 145.0) -> list[Pose]:
    """Independent random poses as in the reference design's evaluation.

    |alpha|, |beta| < asin(2r / L) and |dx|, |dy| < r uniformly, kept only when
    dx² + dy² < r² and the centre of the laser plane lies inside the pipe.
    """
    limit = np.arcsin(min(1.0, 2 * radius_mm / body_length_mm))
    section = PipeSection(radius_mm)
    poses: list[Pose] = []
    while len(poses) < n:
        a, b = rng.uniform(-limit, limit, 2)
        dx, dy = rng.uniform(-radius_mm, radius_mm, 2)
        if dx * dx + dy * dy >= radius_mm**2:
            continue
        pose = Pose(a, b, dx, dy, 0.0, 0.0)
        centre = pose.to_world(np.array([[0.0, 0.0, plane_distance_mm]]))
        if section.clearance_mm(centre)[0] > 0:
            poses.append(pose)
    return poses


def odometer_readings(z_mm: np.ndarray, rng: np.random.Generator, *, scale_error: float = 0.02,
                      noise_mm: float = 0.3, slip_probability: float = 0.0,
                      slip_mm: float = 4.0) -> np.ndarray:
    """Cable-counter readings of the true axial positions ``z_mm``.

    The counter starts at 0, has a scale error and noise, and with
    ``slip_probability`` per pair its wheel slips and the reading loses
    (or, for a slack cable, gains) up to ``slip_mm`` from then on.
    """
    z = np.asarray(z_mm, float) - z_mm[0]
    slips = rng.random(z.size) < slip_probability
    offset = np.cumsum(np.where(slips, rng.uniform(-slip_mm, slip_mm, z.size), 0.0))
    return z * (1 + scale_error) + rng.normal(0, noise_mm, z.size) + offset
