"""Elementary rotations, vectorised over angle arrays (radians).

``rot_x(a)`` etc. return (..., 3, 3) matrices acting on column vectors, so a row
array of points ``P`` (N, 3) rotates as ``P @ R.T``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rot_x", "rot_y", "rot_z"]


def _rot(angle: np.ndarray | float, i: int, j: int) -> np.ndarray:
    if isinstance(angle, (float, int, np.floating, np.integer)):
        return _rot_of(float(angle), i, j)
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., :, :] = np.eye(3)
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _rot_of(angle: float, i: int, j: int) -> np.ndarray:
    """:func:`_rot` of one angle: written out (a pose's rotations are built hundreds of
    thousands of times a run, and the array path's identity-and-fill costs 3x this)."""
    c, s = math.cos(angle), math.sin(angle)
    out = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    out[i][i], out[j][j], out[i][j], out[j][i] = c, c, -s, s
    return np.array(out)


def rot_x(angle: np.ndarray | float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about x: y -> z."""
    return _rot(angle, 1, 2)


def rot_y(angle: np.ndarray | float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about y: z -> x."""
    return _rot(angle, 2, 0)


def rot_z(angle: np.ndarray | float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about z: x -> y."""
    return _rot(angle, 0, 1)
