"""Probe trajectories for the simulator.

``wandering_poses`` (a :class:`WanderingTrack`'s poses at its pairs) moves a rigid
probe body (a cylinder of the probe.toml length and diameter, behind the camera
centre) along the pipe with a slowly wandering tilt and offset that always keeps the
body inside the pipe, plus a slowly varying roll; the track gives the pose anywhere
along the way (an LED frame taken as the probe moves on from its laser frame's). The
wander is generated for the body's front and rear axis points, which is how a real
probe moves (each end slides on the wall), and the pose is derived from them.
``table1_poses`` draws independent poses as the reference design's evaluation.
"""

from __future__ import annotations

import numpy as np

from pipestitch.geometry import BodyEnvelope, PipeSection, Pose

__all__ = ["WanderingTrack", "odometer_readings", "table1_poses", "wandering_poses"]


class _SmoothWalk:
    """A smooth 2-D random curve over z: a sum of random sinusoids, divided by its
    largest norm at the z it was drawn for."""

    def __init__(self, z: np.ndarray, rng: np.random.Generator,
                 wavelengths_mm: tuple[float, float], n_terms: int = 4) -> None:
        self.lam = rng.uniform(*wavelengths_mm, size=(n_terms, 1))
        self.phase = rng.uniform(0, 2 * np.pi, size=(n_terms, 2))
        self.amp = rng.uniform(0.3, 1.0, size=(n_terms, 1))
        self.norm = 1.0
        self.norm = max(np.max(np.linalg.norm(self(z), axis=1)), 1e-12)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * z[None, :] / self.lam
        xy = np.stack([np.sum(self.amp * np.sin(arg + self.phase[:, :1]), 0),
                       np.sum(self.amp * np.sin(arg + self.phase[:, 1:]), 0)], axis=1)
        return xy / self.norm


def _pose_from_ends(front: np.ndarray, rear: np.ndarray, length_mm: float, roll: float,
                    z_mm: float) -> Pose:
    """Pose whose camera centre is at ``front`` and whose axis passes over ``rear``."""
    axis = np.array([front[0] - rear[0], front[1] - rear[1], length_mm])
    axis /= np.linalg.norm(axis)
    # Probe z axis in the world is Rx(alpha)·Ry(beta)·e3 = (sin b, -sin a cos b, cos a cos b).
    beta = np.arcsin(axis[0])
    alpha = np.arctan2(-axis[1], axis[2])
    return Pose(alpha, beta, float(front[0]), float(front[1]), roll, z_mm)


class WanderingTrack:
    """A probe's smooth path along the pipe (see :func:`wandering_poses`): its poses at
    any axial positions, and the positions of its pairs (``z_mm``)."""

    def __init__(self, n_pairs: int, section: PipeSection, body: BodyEnvelope,
                 rng: np.random.Generator, *, step_mm: float = 5.0,
                 step_jitter_mm: float = 0.4, wander: float = 0.8,
                 roll_amplitude_deg: float = 6.0, z_start_mm: float = 0.0,
                 margin_mm: float = 0.3) -> None:
        steps = np.clip(rng.normal(step_mm, step_jitter_mm, n_pairs), 0.2 * step_mm, None)
        self.z_mm = z_start_mm + np.concatenate([[0.0], np.cumsum(steps[1:])])
        play = min(section.a_mm, section.b_mm) - body.diameter_mm / 2 - margin_mm
        if play <= 0:
            raise ValueError(f"probe body of {body.diameter_mm} mm does not fit the pipe")
        self._front = _SmoothWalk(self.z_mm, rng, (120.0, 500.0))
        self._rear = _SmoothWalk(self.z_mm, rng, (120.0, 500.0))
        self._play, self._wander = play, wander
        self._roll = (np.deg2rad(roll_amplitude_deg), rng.uniform(300, 900),
                      rng.uniform(0, 2 * np.pi))
        self._section, self._body, self._margin = section, body, margin_mm

    def poses(self, z_mm: np.ndarray) -> list[Pose]:
        """The probe's poses where its camera centre is at each of ``z_mm``."""
        z = np.asarray(z_mm, float)
        front = self._front(z) * self._play * self._wander
        rear = self._rear(z) * self._play * self._wander
        amplitude, wavelength, phase = self._roll
        roll = amplitude * np.sin(2 * np.pi * z / wavelength + phase)
        return [self._clear(front[i], rear[i], float(roll[i]), float(z[i]))
                for i in range(z.size)]

    def _clear(self, front: np.ndarray, rear: np.ndarray, roll: float, z_mm: float) -> Pose:
        shrink = 1.0
        while True:  # the rims tilt outwards a little: shrink until the body clears the wall
            pose = _pose_from_ends(front * shrink, rear * shrink, self._body.length_mm, roll,
                                   z_mm)
            if self._body.clearance_mm(pose, self._section) >= self._margin or shrink < 0.05:
                return pose
            shrink *= 0.97

    def led_positions(self, share: float) -> np.ndarray:
        """Where the probe is when each pair's LED frame is taken ``share`` of the step
        to the next pair after its laser frame (negative: before, from the previous
        pair); the run's last (first) pair steps as the one before (after) it."""
        z = self.z_mm
        if z.size < 2 or share == 0:
            return z.copy()
        steps = np.diff(z)
        ahead = np.append(steps, steps[-1]) if share > 0 else np.insert(steps, 0, steps[0])
        return z + share * ahead


def wandering_poses(n_pairs: int, section: PipeSection, body: BodyEnvelope,
                    rng: np.random.Generator, **kwargs: float) -> list[Pose]:
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
    **kwargs
        :class:`WanderingTrack`'s: ``step_mm``, ``step_jitter_mm`` (mean axial advance
        per pair and its standard deviation), ``wander`` (fraction, 0..1, of the free
        radial play the body's ends use), ``roll_amplitude_deg`` (of the slow roll about
        the pipe axis), ``z_start_mm`` (the first pose's axial position), ``margin_mm``
        (smallest allowed gap between body and wall).
    """
    track = WanderingTrack(n_pairs, section, body, rng, **kwargs)
    return track.poses(track.z_mm)


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
