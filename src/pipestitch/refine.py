"""Photometric pose refinement: the tilt the ring measures poorly, from the LED frames.

The laser ring measures the tilt only to second order (the ellipse's axis ratio is
1/cos(tilt)), so near zero tilt a few microns of ring error read as a degree. The
LED frames measure it to first order: a frame unwrapped with a pose that is off by
e is warped by G(n)·e (G: how a strip node moves on the wall per unit pose error),
and two overlapping frames with different warps disagree locally. So:

1. between every pair of registered strips, the residual local shift of 64 x 64
   patches after the pair's rigid shift is measured by phase correlation
   (:func:`patch_shifts`);
2. G is computed for each frame at the patch centres by finite differences through
   the camera model and the wall (:func:`node_jacobian`);
3. one sparse linear least-squares problem over all frames' pose errors (4 each) and
   a rigid nuisance shift per pair, with the ring's own information matrix as the
   prior of each frame, is solved with Huber reweighting (:func:`solve_pose_errors`).

Written by hand because no library fuses these two kinds of evidence; the pieces
(phase correlation, sparse solve) are OpenCV's and SciPy's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, rays_to_wall, theta_z_from_points
from pipestitch.register import phase_shift
from pipestitch.unwrap import StripGrid

__all__ = ["PatchShifts", "node_jacobian", "patch_shifts", "solve_pose_errors"]

PATCH_PX = 64
PATCH_STEP_PX = 64         # non-overlapping: hundreds per pair are plenty
MIN_RESPONSE = 0.1
MIN_CONTRAST = 0.01          # patches flatter than this (std of local contrast) are skipped
SHIFT_SIGMA_PX = 0.15        # 1-sigma of a patch shift at response 1
EPS = np.array([2e-4, 2e-4, 2e-3, 2e-3])  # finite-difference steps (rad, rad, mm, mm)
# Weak extra prior on every pose error (rad, rad, mm, mm): keeps frames that no
# patch constrains where the ring put them.
PRIOR_SIGMA = np.array([np.deg2rad(5.0), np.deg2rad(5.0), 5.0, 5.0])


@dataclass(frozen=True)
class PatchShifts:
    """Residual local shifts between strip i and strip j (in j's strip coordinates).

    ``nodes`` (N, 2) are patch centres in strip j as (row, col); ``shift`` (N, 2) is
    where that wall lies in strip i minus ``nodes`` (rows, cols), rigid part included;
    ``response`` (N,) the phase-correlation peaks.
    """

    i: int
    j: int
    nodes: np.ndarray
    shift: np.ndarray
    response: np.ndarray


def patch_shifts(first: np.ndarray, first_valid: np.ndarray, second: np.ndarray,
                 second_valid: np.ndarray, motion_px: tuple[float, float], i: int,
                 j: int) -> PatchShifts:
    """Local shifts of textured patches of ``second`` (frame j) against ``first`` (frame i).

    Parameters
    ----------
    first, second : numpy.ndarray
        Local-contrast strips on the same grid (0 where invalid).
    first_valid, second_valid : numpy.ndarray
        Boolean validity of their nodes.
    motion_px : (float, float)
        Rigid motion (rows, cols) from i to j: strip_j(n) ~ strip_i(n + motion).
    """
    n_rows, n_cols = second.shape
    dr, dc = round(motion_px[0]), round(motion_px[1])
    win = cv2.createHanningWindow((PATCH_PX, PATCH_PX), cv2.CV_32F)
    nodes, shifts, responses = [], [], []
    for c in range(0, n_cols - PATCH_PX + 1, PATCH_STEP_PX):
        c1 = c + dc
        if c1 < 0 or c1 + PATCH_PX > n_cols:
            continue
        for r in range(0, n_rows, PATCH_STEP_PX):
            rows_j = np.arange(r, r + PATCH_PX) % n_rows
            rows_i = (rows_j + dr) % n_rows
            if not (second_valid[rows_j, c:c + PATCH_PX].all()
                    and first_valid[rows_i, c1:c1 + PATCH_PX].all()):
                continue
            b = second[rows_j, c:c + PATCH_PX]
            a = first[rows_i, c1:c1 + PATCH_PX]
            if np.std(b) < MIN_CONTRAST or np.std(a) < MIN_CONTRAST:
                continue
            sx, sy, resp = phase_shift(a, b, win, iterations=2)
            if resp < MIN_RESPONSE or max(abs(sx), abs(sy)) > PATCH_PX / 4:
                continue
            # b(x) = a(x - s): the wall at b's x is at a's x - s, i.e. strip i's n + d - s.
            nodes.append((r + (PATCH_PX - 1) / 2, c + (PATCH_PX - 1) / 2))
            shifts.append((dr - sy, dc - sx))
            responses.append(resp)
    return PatchShifts(i, j, np.array(nodes, float).reshape(-1, 2),
                       np.array(shifts, float).reshape(-1, 2), np.array(responses, float))


def node_jacobian(camera: CameraModel, pose: Pose, section: PipeSection, grid: StripGrid,
                  nodes: np.ndarray) -> np.ndarray:
    """How strip nodes move on the wall per unit pose error: (N, 2, 4) in (rows, cols).

    For an error e in (alpha, beta, dx, dy) (radians, mm) of the pose the strip was
    unwrapped with, the wall actually shown at node n is at node n + G(n)·e of a strip
    unwrapped with the right pose. Forward differences through the camera model.
    """
    nodes = np.asarray(nodes, float).reshape(-1, 2)
    theta = np.deg2rad(grid.theta0_deg + nodes[:, 0] * grid.deg_per_px)
    z = grid.z0_mm + nodes[:, 1] * grid.mm_per_px
    wall = section.points(theta, z)
    local = Pose(pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm)
    out = np.zeros((len(nodes), 2, 4))
    for k in range(4):
        params = np.array([local.alpha, local.beta, local.dx_mm, local.dy_mm])
        params[k] -= EPS[k]   # the strip's pose is off by +e from the truth
        truth = Pose(*params)
        rays = camera.unproject(camera.project(local.to_probe(wall)))
        seen = rays_to_wall(rays, truth, section)
        th2, z2 = theta_z_from_points(seen)
        d_theta = (np.rad2deg(th2 - theta) + 180.0) % 360.0 - 180.0
        out[:, 0, k] = d_theta / grid.deg_per_px / EPS[k]
        out[:, 1, k] = (z2 - z) / grid.mm_per_px / EPS[k]
    return out


def _prior_root(information: np.ndarray | None) -> np.ndarray:
    """Square root R (R^T R = ring information + weak prior) of one frame's prior."""
    info = np.diag(1.0 / PRIOR_SIGMA**2)
    if information is not None and np.all(np.isfinite(information)):
        info = info + information
    vals, vecs = np.linalg.eigh(0.5 * (info + info.T))
    return (vecs * np.sqrt(np.clip(vals, 0, None))).T


def solve_pose_errors(observations: Sequence[PatchShifts],
                      jacobians: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]],
                      information: Mapping[int, np.ndarray | None], *,
                      iterations: int = 4) -> tuple[dict[int, np.ndarray],
                                                    dict[tuple[int, int], np.ndarray]]:
    """Pose error of every frame and the rigid motion of every pair once it is removed.

    Parameters
    ----------
    observations : sequence of PatchShifts
        Patch shifts per registered pair.
    jacobians : mapping
        (i, j) -> (G_i at the patches' positions in strip i, G_j at the patch nodes),
        each (N, 2, 4), from :func:`node_jacobian`.
    information : mapping
        Frame -> the ring's 4 x 4 information matrix (or None).
    iterations : int
        Huber reweighting rounds (threshold 2 sigma).

    Returns
    -------
    errors : dict
        Frame -> e (alpha, beta, dx, dy; rad, mm); subtract it from the pose.
    motions : dict
        (i, j) -> rigid motion (rows, cols) from strip i to strip j of the corrected
        strips: the registration link free of the pose errors' warp.
    """
    frames = sorted(information)
    col = {f: 4 * k for k, f in enumerate(frames)}
    n_pose = 4 * len(frames)
    obs = [o for o in observations if len(o.nodes) and o.i in col and o.j in col]
    rows, cols, vals, rhs, sigma = [], [], [], [], []
    row = 0
    for link, o in enumerate(obs):
        g_i, g_j = jacobians[(o.i, o.j)]
        nuisance = n_pose + 2 * link
        for p in range(len(o.nodes)):
            for axis in range(2):
                # shift = c_link + G_j e_j - G_i e_i
                rows += [row] * 9
                cols += [nuisance + axis, *range(col[o.j], col[o.j] + 4),
                         *range(col[o.i], col[o.i] + 4)]
                vals += [1.0, *g_j[p, axis], *(-g_i[p, axis])]
                rhs.append(o.shift[p, axis])
                sigma.append(SHIFT_SIGMA_PX / np.sqrt(o.response[p]))
                row += 1
    n_obs = row
    for f in frames:
        root = _prior_root(information[f])
        for r in range(4):
            rows += [row] * 4
            cols += list(range(col[f], col[f] + 4))
            vals += list(root[r])
            rhs.append(0.0)
            sigma.append(1.0)
            row += 1
    n_unknown = n_pose + 2 * len(obs)
    a = sp.csr_matrix((vals, (rows, cols)), shape=(row, n_unknown))
    b, s = np.array(rhs), np.array(sigma)
    weight = 1.0 / s**2
    x = np.zeros(n_unknown)
    for _ in range(iterations):
        w = sp.diags(weight)
        normal = (a.T @ w @ a + sp.identity(n_unknown) * 1e-9).tocsc()
        x = spsolve(normal, a.T @ (weight * b))
        z = np.abs(a @ x - b) / s
        huber = np.where(z[:n_obs] > 2.0, 2.0 / np.maximum(z[:n_obs], 1e-12), 1.0)
        weight = np.concatenate([huber / s[:n_obs] ** 2, 1.0 / s[n_obs:] ** 2])
    errors = {f: x[col[f]:col[f] + 4] for f in frames}
    motions = {(o.i, o.j): x[n_pose + 2 * k:n_pose + 2 * k + 2] for k, o in enumerate(obs)}
    return errors, motions
