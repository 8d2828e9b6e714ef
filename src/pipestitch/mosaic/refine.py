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
   prior of each frame, is solved with Huber reweighting (:func:`solve_pose_errors`;
   its normal equations are summed pair by pair, so its memory is a few kB a frame);
   a long run is solved in overlapping windows of frames (:func:`solve_in_windows`),
   so that this memory does not grow with the run;
4. each frame's covariance is read from the solution (:func:`_pose_covariances`):
   the patch shifts' noise model, scaled up where the residuals scatter more, through
   the inverse normal matrix's diagonal blocks (its banded pose part inverted within
   the band, :func:`_inverse_in_band`).

Written by hand because no library fuses these two kinds of evidence; the pieces
(phase correlation, sparse solve, banded Cholesky) are OpenCV's and SciPy's.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.linalg import cholesky_banded
from scipy.sparse.linalg import splu, spsolve

from pipestitch.camera import CameraModel
from pipestitch.geometry import PipeSection, Pose, WallGrid, rays_to_wall, theta_z_from_points
from pipestitch.mosaic._register_kernels import link_patches, patches_valid, polish_patches
from pipestitch.mosaic.noise import ContrastNoise, patch_noise_sums
from pipestitch.mosaic.register import MIN_SIGNAL_SHARE, weight_total

__all__ = ["PatchShifts", "node_jacobian", "pair_jacobians", "patch_shifts", "prior_share",
           "refinement_windows", "solve_in_windows", "solve_pose_errors"]

PATCH_PX = 64
PATCH_STEP_PX = 64         # non-overlapping: hundreds per pair are plenty
# The grid of patches is at most this many around the pipe (wider steps, around and
# along, on strips of more rows): the warp a pose error makes is smooth over the
# strip, so a full-size strip's 2-4x more patches measure it no better, at 2-4x the
# cost (chart83 at full size: 12 around or 24, the same SSIM 0.90 and tilt error 0.007°).
PATCHES_AROUND = 12
# the patches' taper, shared by every link (never written to)
_PATCH_WINDOW = cv2.createHanningWindow((PATCH_PX, PATCH_PX), cv2.CV_32F)
_WINDOW_TOTAL = weight_total(_PATCH_WINDOW)
MIN_RESPONSE = 0.1
MIN_CONTRAST = 0.01          # patches flatter than this (std of local contrast) are skipped
SHIFT_SIGMA_PX = 0.15        # 1-sigma of a patch shift at response 1
EPS = np.array([2e-4, 2e-4, 2e-3, 2e-3])  # finite-difference steps (rad, rad, mm, mm)
# Weak extra prior on every pose error (rad, rad, mm, mm): keeps frames that no
# patch constrains where the ring put them.
PRIOR_SIGMA = np.array([np.deg2rad(5.0), np.deg2rad(5.0), 5.0, 5.0])


@dataclass(frozen=True, slots=True)
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
                 j: int, first_noise: ContrastNoise | None = None) -> PatchShifts:
    """Local shifts of textured patches of ``second`` (frame j) against ``first`` (frame i).

    Parameters
    ----------
    first, second : numpy.ndarray
        Local-contrast strips on the same grid (0 where invalid).
    first_valid, second_valid : numpy.ndarray
        Boolean validity of their nodes.
    motion_px : (float, float)
        Rigid motion (rows, cols) from i to j: strip_j(n) ~ strip_i(n + motion).
    first_noise : ContrastNoise, optional
        The noise fields of ``first`` (:func:`pipestitch.mosaic.noise.contrast_noise`):
        each patch's shift is then corrected for its noise (:mod:`pipestitch.mosaic.noise`).

    Patches of ``PATCH_PX`` every ``PATCH_STEP_PX``, or every ``1 / PATCHES_AROUND``
    of the rows when that is wider.
    """
    n_rows = second.shape[0]
    step = max(PATCH_STEP_PX, n_rows // PATCHES_AROUND)
    dr, dc = round(motion_px[0]), round(motion_px[1])
    win = _PATCH_WINDOW
    valid = patches_valid(np.ascontiguousarray(first_valid, np.bool_),
                          np.ascontiguousarray(second_valid, np.bool_), PATCH_PX, step, dr, dc)
    # every patch pair at once, less its weighted mean (phase_shift's first step)
    a, b, where = link_patches(np.asarray(first, np.float32), np.asarray(second, np.float32),
                               valid, step, dr, dc, win, _WINDOW_TOTAL, MIN_CONTRAST)
    peaks = np.empty((len(where), 2))
    response = np.empty(len(where))
    for k in range(len(where)):
        peaks[k], response[k] = cv2.phaseCorrelate(a[k], b[k], win)
    noise = (np.empty((0, 4)) if first_noise is None
             else patch_noise_sums(first_noise.patch_table(win), first_noise.step,
                                   where[:, 2], where[:, 3]))
    sx, sy = polish_patches(a, b, win, peaks, 3, noise, MIN_SIGNAL_SHARE).T
    # max(|sx|, |sy|) as Python's max takes it (a NaN first is kept, as it compares false)
    largest = np.where(np.abs(sy) > np.abs(sx), np.abs(sy), np.abs(sx))
    keep = ~(response < MIN_RESPONSE) & ~(largest > PATCH_PX / 4)
    # b(x) = a(x - s): the wall at b's x is at a's x - s, i.e. strip i's n + d - s.
    nodes = where[keep, :2] + (PATCH_PX - 1) / 2
    shifts = np.stack([dr - sy[keep], dc - sx[keep]], axis=1)
    # float32: a run's patch shifts are all held until its refinement (1e-5 px here)
    return PatchShifts(i, j, nodes.astype(np.float32).reshape(-1, 2),
                       shifts.astype(np.float32).reshape(-1, 2),
                       response[keep].astype(np.float32))


def node_jacobian(camera: CameraModel, pose: Pose, section: PipeSection, grid: WallGrid,
                  nodes: np.ndarray) -> np.ndarray:
    """How strip nodes move on the wall per unit pose error: (N, 2, 4) in (rows, cols).

    For an error e in (alpha, beta, dx, dy) (radians, mm) of the pose the strip was
    unwrapped with, the wall actually shown at node n is at node n + G(n)·e of a strip
    unwrapped with the right pose. Forward differences through the camera model.
    """
    nodes = np.asarray(nodes, float).reshape(-1, 2)
    theta = np.deg2rad(grid.theta0_deg + nodes[:, 0] * grid.deg_per_px)
    z = grid.z0_mm + nodes[:, 1] * grid.mm_per_px_axial
    wall = section.points(theta, z)
    local = Pose(pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm)
    # the rays the strip's pixels were taken along: the same for every parameter
    rays = camera.unproject(camera.project(local.to_probe(wall)))
    out = np.zeros((len(nodes), 2, 4))
    for k in range(4):
        params = np.array([local.alpha, local.beta, local.dx_mm, local.dy_mm])
        params[k] -= EPS[k]   # the strip's pose is off by +e from the truth
        truth = Pose(*params)
        seen = rays_to_wall(rays, truth, section)
        th2, z2 = theta_z_from_points(seen)
        d_theta = (np.rad2deg(th2 - theta) + 180.0) % 360.0 - 180.0
        out[:, 0, k] = d_theta / grid.deg_per_px / EPS[k]
        out[:, 1, k] = (z2 - z) / grid.mm_per_px_axial / EPS[k]
    return out


def pair_jacobians(observations: Sequence[PatchShifts],
                   frame_jacobian: Callable[[int, np.ndarray], np.ndarray],
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(G_i, G_j) of each pair, as :func:`solve_pose_errors` takes them.

    Parameters
    ----------
    observations : sequence of PatchShifts
        Patch shifts of the pairs.
    frame_jacobian : callable
        ``frame_jacobian(frame, nodes)``: that frame's :func:`node_jacobian` at nodes
        (N, 2) as (rows, cols), (N, 2, 4), node by node.

    Returns
    -------
    list of (numpy.ndarray, numpy.ndarray)
        Per pair, G_i at the patches' positions in strip i (``nodes + shift``) and G_j
        at its nodes: views of one array per frame.

    Notes
    -----
    Each frame is asked once, with its nodes of every pair it is in: a call costs far
    more than a node (~0.3 ms of camera and wall calls for the ~10 patches of a pair).
    """
    parts: dict[int, list[np.ndarray]] = {}
    for o in observations:
        parts.setdefault(o.i, []).append(o.nodes + o.shift)
        parts.setdefault(o.j, []).append(o.nodes)
    whole = {f: frame_jacobian(f, np.concatenate(p)) for f, p in parts.items()}
    start = dict.fromkeys(whole, 0)
    out = []
    for o in observations:
        g = []
        for f in (o.i, o.j):
            g.append(whole[f][start[f]:start[f] + len(o.nodes)])
            start[f] += len(o.nodes)
        out.append((g[0], g[1]))
    return out


def _prior_root(information: np.ndarray | None) -> np.ndarray:
    """Square root R (R^T R = ring information + weak prior) of one frame's prior."""
    info = np.diag(1.0 / PRIOR_SIGMA**2)
    if information is not None and np.all(np.isfinite(information)):
        info = info + information
    vals, vecs = np.linalg.eigh(0.5 * (info + info.T))
    return (vecs * np.sqrt(np.clip(vals, 0, None))).T


@dataclass(frozen=True)
class _PairRows:
    """The observation rows of one pair: shift = c + G_j e_j - G_i e_i.

    ``unknowns`` (10,) are the columns of (c rows, c cols, e_j, e_i); ``shift`` and
    ``sigma`` (2N,) follow the patches (rows then cols of each).
    """

    i: int
    j: int
    unknowns: np.ndarray
    g_i: np.ndarray
    g_j: np.ndarray
    shift: np.ndarray
    sigma: np.ndarray

    def design(self) -> np.ndarray:
        """(2N, 10) coefficients of the rows on ``unknowns`` (built when needed: the
        Jacobians are all that is kept)."""
        n = len(self.g_i)
        a = np.zeros((n, 2, 10))
        a[:, 0, 0] = a[:, 1, 1] = 1.0
        a[:, :, 2:6] = self.g_j
        a[:, :, 6:] = -self.g_i
        return a.reshape(2 * n, 10)


def _pair_rows(observations: Sequence[PatchShifts],
               jacobians: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]],
               col: Mapping[int, int], held: Collection[int] = ()) -> list[_PairRows]:
    """Rows of every pair with patches between two solved frames (the pairs' nuisance
    unknowns after the frames' 4 each). A ``held`` frame's Jacobian is zero: its error
    is observed by nothing, so its prior alone sets it, to exactly 0."""
    obs = [o for o in observations if len(o.nodes) and o.i in col and o.j in col]
    n_pose, four = 4 * len(col), np.arange(4)
    out = []
    for k, o in enumerate(obs):
        unknowns = np.concatenate([[n_pose + 2 * k, n_pose + 2 * k + 1],
                                   col[o.j] + four, col[o.i] + four])
        sigma = np.repeat(SHIFT_SIGMA_PX / np.sqrt(o.response.astype(np.float64)), 2)
        g_i, g_j = (np.zeros_like(g) if f in held else g
                    for f, g in zip((o.i, o.j), jacobians[(o.i, o.j)], strict=True))
        out.append(_PairRows(o.i, o.j, unknowns, g_i, g_j,
                             o.shift.reshape(-1).astype(np.float64), sigma))
    return out


def _prior_normal(information: Mapping[int, np.ndarray | None], frames: Sequence[int],
                  n_unknown: int) -> sp.coo_matrix:
    """R^T R of every frame's prior (rows of unit sigma, never reweighted), with the
    frame's 4 unknowns at 4 k."""
    blocks = np.array([r.T @ r for r in (_prior_root(information[f]) for f in frames)])
    idx = np.arange(4 * len(frames)).reshape(-1, 4)
    return sp.coo_matrix((blocks.ravel(), (np.repeat(idx, 4, axis=1).ravel(),
                                           np.tile(idx, (1, 4)).ravel())),
                         shape=(n_unknown, n_unknown))


def _normal_pattern(pairs: Sequence[_PairRows],
                    fixed: sp.coo_matrix) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the normal matrix's entries: every pair's 10 x 10 block, then
    ``fixed``'s (the same in every reweighting round)."""
    idx = np.array([p.unknowns for p in pairs], dtype=np.int32).reshape(-1, 10)
    rows = np.concatenate([np.repeat(idx, 10, axis=1).ravel(), fixed.row])
    cols = np.concatenate([np.tile(idx, (1, 10)).ravel(), fixed.col])
    return rows, cols


def _normal_equations(pairs: Sequence[_PairRows], weights: Sequence[np.ndarray],
                      fixed: sp.coo_matrix,
                      pattern: tuple[np.ndarray, np.ndarray]) -> tuple[sp.csc_matrix, np.ndarray]:
    """A^T W A + ``fixed`` and A^T W b, summed pair by pair (each pair's 10 x 10 block
    at ``pattern``, :func:`_normal_pattern`): no matrix with a row per patch shift is
    ever built."""
    n_unknown = fixed.shape[0]
    rhs = np.zeros(n_unknown)
    data = np.empty(100 * len(pairs) + fixed.nnz)
    blocks = data[:100 * len(pairs)].reshape(-1, 10, 10)
    for k, (p, w) in enumerate(zip(pairs, weights, strict=True)):
        a = p.design()
        aw = a * w[:, None]
        blocks[k] = aw.T @ a
        np.add.at(rhs, p.unknowns, aw.T @ p.shift)   # sums repeated unknowns, as += does not
    data[100 * len(pairs):] = fixed.data
    return sp.csc_matrix((data, pattern), shape=(n_unknown, n_unknown)), rhs


def solve_pose_errors(observations: Sequence[PatchShifts],
                      jacobians: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]],
                      information: Mapping[int, np.ndarray | None], *,
                      iterations: int = 4,
                      held: Collection[int] = (),
                      covariances: dict[int, np.ndarray] | None = None,
                      prior_errors: Mapping[int, np.ndarray] | None = None
                      ) -> tuple[dict[int, np.ndarray], dict[tuple[int, int], np.ndarray]]:
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
        Huber reweighting rounds (threshold 2 sigma, the shift model's sigma times the
        residuals' scale where they scatter more: :func:`_residual_scale`).
    held : collection of int
        Frames whose poses are taken as right (error 0): their pairs with the other
        frames still measure those, and the pairs' rigid motions.
    covariances : dict, optional
        Filled with each solved frame's (not held) 4 x 4 covariance of its corrected pose
        (:func:`_pose_covariances`).
    prior_errors : mapping, optional
        Frame -> the error its prior is centred on (default 0: the prior holds the
        pose the strips were unwrapped with; :mod:`pipestitch.pipeline.pair_timing`
        centres it on the ring's pose at the LED frame's instant).

    Returns
    -------
    errors : dict
        Frame -> e (alpha, beta, dx, dy; rad, mm); subtract it from the pose.
    motions : dict
        (i, j) -> rigid motion (rows, cols) from strip i to strip j of the corrected
        strips: the registration link free of the pose errors' warp.

    Notes
    -----
    The normal equations are summed pair by pair, so the working memory is the
    Jacobians plus a 10 x 10 block per pair (~12 kB a frame), not a sparse matrix
    with a row per patch shift (~170 kB a frame when built from Python lists); the
    solution is the same to rounding (1e-12 relative on a 150-pair run).
    """
    frames = sorted(information)
    col = {f: 4 * k for k, f in enumerate(frames)}
    n_pose = 4 * len(frames)
    pairs = _pair_rows(observations, jacobians, col, held)
    centre = np.zeros(n_pose + 2 * len(pairs))
    for f, e in (prior_errors or {}).items():
        if f in col and f not in held:
            centre[col[f]:col[f] + 4] = e
    solved = _reweighted(pairs, _prior_normal(information, frames, centre.size), centre,
                         iterations)
    x = solved.x
    errors = {f: x[col[f]:col[f] + 4] for f in frames}
    motions = {(p.i, p.j): x[p.unknowns[:2]] for p in pairs}
    if covariances is not None and iterations > 0:
        solving = [f for f in frames if f not in held]
        covariances.update(_pose_covariances(solved.normal, n_pose, solved.scale, solving,
                                             [col[f] for f in solving]))
    return errors, motions


def prior_share(observations: Sequence[PatchShifts],
                jacobians: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]],
                information: Mapping[int, np.ndarray | None],
                direction: Mapping[int, np.ndarray], *,
                iterations: int = 4) -> tuple[float, float]:
    """How far the priors' centres move along ``direction`` for the patches to agree
    with them best: the multiple s of it, solved with the poses.

    The problem of :func:`solve_pose_errors` with each frame's prior centred on s times
    its ``direction`` (frames not in it: on 0) and s one more unknown, eliminated: the
    normal matrix N is factored once a reweighting round and solved for the patches'
    right-hand side and for the priors' pull along the direction (P d), and
    s = d^T P x0 / (d^T P d - (P d)^T N^-1 P d), its variance the residuals' scale
    squared over that denominator (the Schur complement of N in the bordered matrix).

    Parameters
    ----------
    observations, jacobians, information, iterations
        As :func:`solve_pose_errors`.
    direction : mapping
        Frame -> a pose error (alpha, beta, dx, dy; rad, mm): where its prior's centre
        goes at s = 1.

    Returns
    -------
    share, sigma : float
        s and its standard deviation (large where the direction moves the priors
        little); (0, inf) where it moves none, or the problem cannot be solved (a
        singular or non-finite normal matrix).
    """
    frames = sorted(information)
    col = {f: 4 * k for k, f in enumerate(frames)}
    pairs = _pair_rows(observations, jacobians, col)
    along = np.zeros(4 * len(frames) + 2 * len(pairs))
    for f, d in direction.items():
        if f in col:
            along[col[f]:col[f] + 4] = d
    solved = _reweighted(pairs, _prior_normal(information, frames, along.size),
                         np.zeros(along.size), iterations, along)
    return solved.share, solved.share_sigma


@dataclass(frozen=True)
class _Solved:
    x: np.ndarray
    normal: sp.csc_matrix   # the last round's (its weights)
    scale: float            # the residuals' scale against the shift model
    share: float = 0.0
    share_sigma: float = float("inf")


def _reweighted(pairs: Sequence[_PairRows], prior: sp.coo_matrix, centre: np.ndarray,
                iterations: int, along: np.ndarray | None = None) -> _Solved:
    """The least-squares solution with Huber reweighting: the pairs' rows, each frame's
    prior (information ``prior``, centred on ``centre``, moved by s ``along`` when that
    is given: :func:`prior_share`) and a ridge of 1e-9 on every unknown."""
    n_unknown = centre.size
    fixed = (prior + sp.identity(n_unknown, format="coo") * 1e-9).tocoo()
    by_row = prior.tocsr()
    prior_rhs = by_row @ centre
    pull = None if along is None else by_row @ along
    pattern = _normal_pattern(pairs, fixed)
    weights = [1.0 / p.sigma**2 for p in pairs]
    x, normal, scale, share, schur = np.zeros(n_unknown), None, 1.0, 0.0, 0.0
    for _ in range(iterations):
        normal, rhs = _normal_equations(pairs, weights, fixed, pattern)
        if pull is None:
            x = spsolve(normal, rhs + prior_rhs)
        else:
            try:
                factor = splu(normal)
            except RuntimeError:   # singular or not finite (spsolve gives NaN there)
                return _Solved(np.full(n_unknown, np.nan), normal, scale)
            x, moved = factor.solve(rhs + prior_rhs), factor.solve(pull)
            schur = float(along @ pull - pull @ moved)
            share = float(pull @ (x - centre)) / schur if schur > 0 else 0.0
            x = x + share * moved
        z = [np.abs(p.design() @ x[p.unknowns] - p.shift) / p.sigma for p in pairs]
        scale = _residual_scale(z, len(pairs))
        weights = [_huber(zk / scale) / p.sigma**2 for zk, p in zip(z, pairs, strict=True)]
    sigma = scale / np.sqrt(schur) if schur > 0 else float("inf")
    return _Solved(x, normal, scale, share, sigma)


def _residual_scale(z: Sequence[np.ndarray], n_pairs: int) -> float:
    """How many times the shift model's noise the patch rows' residuals (``z``, each
    pair's normalised by its model sigma) scatter, at least 1: their median absolute
    value over that of a unit normal, corrected for the unknowns each pair's rows
    fit (its rigid shift; the poses, shared by many pairs, are left out).

    The model (``SHIFT_SIGMA_PX`` at response 1) is what a clean texture gives or less
    (0.02-0.4 of it on 18 simulated runs); a noisier one exceeds it, and the Huber
    threshold and the covariance follow (:func:`_pose_covariances`)."""
    rows = np.concatenate(z) if z else np.zeros(0)
    redundancy = len(rows) - 2 * n_pairs
    if redundancy <= 0:
        return 1.0
    mad = float(np.median(rows)) / 0.6744897501960817   # a unit normal's median |z|
    return max(1.0, mad * np.sqrt(len(rows) / redundancy))


def _pose_covariances(normal: sp.csc_matrix, n_pose: int, scale: float,
                      frames: Sequence[int], starts: Sequence[int]) -> dict[int, np.ndarray]:
    """Each of ``frames``' 4 x 4 block (at ``starts``) of the solution's covariance,
    scale^2 N^-1 (N: the normal matrix of the last solve, its weights; ``scale``: the
    residuals' scale against the shift model, :func:`_residual_scale`).

    The pairs' unknowns are eliminated (their blocks are 2 x 2), which leaves the poses'
    matrix banded (a pair links frames a few apart); the blocks come from its banded
    Cholesky factor (:func:`_inverse_in_band`). Empty when that matrix is not finite or
    not positive definite.

    The scale multiplies the priors' share of N too, which the patch residuals say
    nothing of: where a prior weighs in, scale^2 N^-1 bounds the solution's covariance
    (N^-1 (scale^2 N_data + N_prior) N^-1) from above.
    """
    if not frames or not np.all(np.isfinite(normal.data)):
        return {}
    try:
        band = _inverse_in_band(_pose_band(normal, n_pose))
    except np.linalg.LinAlgError:
        return {}
    out: dict[int, np.ndarray] = {}
    upper = np.triu_indices(4)
    for f, c in zip(frames, starts, strict=True):
        block = np.zeros((4, 4))
        block[upper] = band[c + upper[0], upper[1] - upper[0]]
        out[f] = scale**2 * (block + np.triu(block, 1).T)
    return out


def _pose_band(normal: sp.csc_matrix, n_pose: int) -> np.ndarray:
    """The poses' normal matrix with the pairs' unknowns eliminated (Schur complement
    N_pp - N_pc N_cc^-1 N_cp; N_cc is 2 x 2 blocks along its diagonal), in the lower
    banded form of :func:`scipy.linalg.cholesky_banded`."""
    n_pair = (normal.shape[0] - n_pose) // 2
    csr = normal.tocsr()
    cc = csr[n_pose:, n_pose:]
    a, b, d = cc.diagonal()[0::2], cc.diagonal(1)[0::2], cc.diagonal()[1::2]
    det = a * d - b * b
    idx = np.arange(n_pair)
    inv = sp.bsr_matrix((np.stack([np.stack([d, -b], 1), np.stack([-b, a], 1)], 1)
                         / det[:, None, None], idx, np.arange(n_pair + 1)),
                        shape=(2 * n_pair, 2 * n_pair))
    pc = csr[:n_pose, n_pose:]
    reduced = (csr[:n_pose, :n_pose] - pc @ inv.tocsr() @ pc.T).tocoo()
    low = reduced.row >= reduced.col
    rows, cols, vals = reduced.row[low], reduced.col[low], reduced.data[low]
    # at least a frame's 4 x 4 block wide (lags 0-3), whatever the priors hold
    width = max(int(np.max(rows - cols, initial=0)), min(3, n_pose - 1)) + 1
    band = np.zeros((width, n_pose))
    np.add.at(band, (rows - cols, cols), vals)
    return band


def _inverse_in_band(band: np.ndarray) -> np.ndarray:
    """The entries of A^-1 within A's band: ``out[i, d]`` = (A^-1)[i, i + d].

    ``band`` is A (symmetric positive definite) in the lower banded form of
    :func:`scipy.linalg.cholesky_banded`. From A = L L^T, L^T Z = L^-1 gives, for j >= i,
    Z_ij = (delta_ij / L_ii - sum_k L_ki Z_kj) / L_ii over the k below i within the band
    (Takahashi's recurrence), run from the last row up: O(n w^2) for band width w,
    where unit right-hand sides cost O(n^2 w). Written by hand: SciPy has banded
    factors and solves but no selected inversion.

    Raises
    ------
    numpy.linalg.LinAlgError
        When A is not positive definite.
    """
    factor = cholesky_banded(band, lower=True)
    w, n = factor.shape[0] - 1, factor.shape[1]
    for d in range(1, w + 1):
        factor[d, n - d:] = 0.0   # past the last row: not part of L
    out = np.zeros((n + w, w + 1))   # rows past n: zeros for the last rows' windows
    k, j = np.meshgrid(np.arange(w), np.arange(w), indexing="ij")
    row, lag = np.minimum(k, j), np.abs(k - j)   # Z[i+1+k, i+1+j] = out[i+1+min, |k-j|]
    for i in range(n - 1, -1, -1):
        below = factor[1:, i]                    # L[i+1 .. i+w, i]
        window = out[i + 1 + row, lag]
        diag = factor[0, i]
        out[i, 1:] = -(below @ window) / diag
        out[i, 0] = (1.0 / diag - below @ out[i, 1:]) / diag
    return out[:n]


WINDOW_FRAMES = 600   # frames per solve of a long run (a 250-pair run is one solve)
WINDOW_MARGIN = 100   # frames on each side of a window's kept core


def refinement_windows(n_frames: int, window: int = WINDOW_FRAMES,
                       margin: int = WINDOW_MARGIN) -> list[tuple[int, int, int, int]]:
    """Overlapping windows of a run's frames: (lo, hi, core_lo, core_hi) positions.

    The cores tile ``0 .. n_frames`` in order; each window reaches ``margin`` frames
    beyond its core (where the run has them) and spans at most ``window`` frames. One
    window when the run fits in one.

    Parameters
    ----------
    n_frames : int
        Frames of the run.
    window, margin : int
        Frames a window spans at most, and of context on each side of its core
        (``window`` > 2 ``margin``).

    Returns
    -------
    list of (int, int, int, int)
        Each window's span ``lo .. hi`` and kept core ``core_lo .. core_hi``.
    """
    if window <= 2 * margin:
        raise ValueError(f"refinement_windows: window {window} must exceed twice the "
                         f"margin {margin}")
    out, core_lo = [], 0
    while core_lo < n_frames or not out:
        lo = max(0, core_lo - margin)
        hi = min(n_frames, lo + window)
        core_hi = n_frames if hi == n_frames else hi - margin
        out.append((lo, hi, core_lo, core_hi))
        core_lo = core_hi
    return out


def solve_in_windows(observations: Sequence[PatchShifts],
                     jacobians_of: Callable[[Sequence[PatchShifts]],
                                            Sequence[tuple[np.ndarray, np.ndarray]]],
                     information: Mapping[int, np.ndarray | None], *,
                     window: int = WINDOW_FRAMES, margin: int = WINDOW_MARGIN,
                     iterations: int = 4,
                     held: Collection[int] = (),
                     covariances: dict[int, np.ndarray] | None = None,
                     prior_errors: Mapping[int, np.ndarray] | None = None
                     ) -> tuple[dict[int, np.ndarray], dict[tuple[int, int], np.ndarray]]:
    """:func:`solve_pose_errors` over overlapping windows of frames (bounded memory).

    The working memory is that of one window however long the run is.

    Each window solves its frames and the pairs between them; it keeps the errors of
    its core's frames and the motions of the pairs whose later frame is in its core (a
    pair reaching back past the window's margin widens the window to its earlier
    frame, so every pair is solved).
    A frame's pose error is tied to its neighbours only through the patches of the few
    links between them, each frame having its ring's prior, so ``margin`` frames of
    context on each side leave a core's solution as the whole run's to far below its
    uncertainty (tested). ``jacobians_of(observations)`` gives each pair's (G_i, G_j)
    as :func:`solve_pose_errors` takes them (:func:`pair_jacobians`); it is called once
    a window, with the pairs no earlier window asked for, so each pair's are computed
    once, and dropped when no later window needs them.

    Parameters
    ----------
    observations, information, iterations, held, covariances, prior_errors
        As :func:`solve_pose_errors` (``covariances``: each core frame's from its
        window).
    jacobians_of : callable
        The pairs' Jacobians, as above.
    window, margin : int
        Frames a window spans at most, and of context on each side of its core
        (:func:`refinement_windows`).

    Returns
    -------
    errors, motions
        As :func:`solve_pose_errors`.
    """
    frames = sorted(information)
    position = {f: k for k, f in enumerate(frames)}
    obs = [o for o in observations if len(o.nodes) and o.i in position and o.j in position]
    # each pair's (earlier, later) frame positions
    span = {(o.i, o.j): (min(position[o.i], position[o.j]), max(position[o.i], position[o.j]))
            for o in obs}
    errors: dict[int, np.ndarray] = {}
    motions: dict[tuple[int, int], np.ndarray] = {}
    jac: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    for lo, hi, core_lo, core_hi in refinement_windows(len(frames), window, margin):
        # a pair reaching back beyond the margin (frames between it unread) widens
        # the window to its earlier frame, so that every pair is solved once
        lo = min([lo] + [first for first, last in span.values() if core_lo <= last < core_hi])
        inside = [o for o in obs if lo <= span[(o.i, o.j)][0] and span[(o.i, o.j)][1] < hi]
        for key in [k for k in jac if span[k][0] < lo]:
            del jac[key]   # no later window reaches back this far
        new = [o for o in inside if (o.i, o.j) not in jac]
        jac.update(zip([(o.i, o.j) for o in new], jacobians_of(new), strict=True))
        cov: dict[int, np.ndarray] | None = None if covariances is None else {}
        e, m = solve_pose_errors(inside, jac, {f: information[f] for f in frames[lo:hi]},
                                 iterations=iterations, held=held, covariances=cov,
                                 prior_errors=prior_errors)
        errors.update((f, e[f]) for f in frames[core_lo:core_hi])
        if covariances is not None and cov:
            covariances.update((f, cov[f]) for f in frames[core_lo:core_hi] if f in cov)
        motions.update((k, v) for k, v in m.items() if core_lo <= span[k][1] < core_hi)
    return errors, motions


def _huber(z: np.ndarray) -> np.ndarray:
    """Huber weights at 2 sigma of normalised residuals ``z``."""
    return np.where(z > 2.0, 2.0 / np.maximum(z, 1e-12), 1.0)
