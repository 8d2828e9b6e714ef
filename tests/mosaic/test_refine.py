"""Pose refinement from the strips' local warps: patch shifts and the node Jacobian."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose, WallGrid
from pipestitch.mosaic.refine import (
    PATCHES_AROUND,
    SHIFT_SIGMA_PX,
    PatchShifts,
    _inverse_in_band,
    node_jacobian,
    pair_jacobians,
    patch_shifts,
    prior_share,
    solve_in_windows,
    solve_pose_errors,
)
from pipestitch.mosaic.unwrap import unwrap_maps
from pipestitch.pipeline.pair_timing import patch_led_share

R = 32.5


def _given(jacobians: dict) -> Callable[[list[PatchShifts]], list]:
    """``solve_in_windows``' ``jacobians_of`` over Jacobians given by pair."""
    return lambda new: [jacobians[(o.i, o.j)] for o in new]


CAMERA = default_camera("half")


def test_patch_shifts_measure_local_motion(texture, shifted) -> None:
    wall = texture((400, 400), seed=2)
    first = wall[:, :300] - 0.5
    second = (shifted(wall, 3.0, 20.25)[:, :300] - 0.5).astype(np.float32)
    valid = np.ones_like(first, bool)
    found = patch_shifts(first, valid, second, valid, (3.0, 20.0), 0, 1)
    assert len(found.nodes) > 10
    assert np.allclose(found.shift, [3.0, 20.25], atol=0.05)
    # a strip of many rows (a full-size sensor's) gets at most PATCHES_AROUND around
    tall = np.vstack([first] * 8)
    found = patch_shifts(tall, np.ones_like(tall, bool), np.vstack([second] * 8),
                         np.ones_like(tall, bool), (3.0, 20.0), 0, 1)
    rows = np.unique(found.nodes[:, 0])
    assert np.all(np.diff(rows) == tall.shape[0] // PATCHES_AROUND)
    assert PATCHES_AROUND <= len(rows) <= PATCHES_AROUND + 1   # the step rounds down
    assert np.allclose(found.shift, [3.0, 20.25], atol=0.05)


def test_node_jacobian_predicts_the_strip_warp_of_a_pose_error() -> None:
    """Unwrap one frame with the true pose and with a slightly wrong one: the wall
    moves between the two strips by G·e, as node_jacobian says."""
    grid = WallGrid.window(R, 0.135, 5.0, 40.0)
    true = Pose.from_degrees(1.0, -0.5, 2.0, 1.0)
    error = np.array([np.deg2rad(0.3), np.deg2rad(-0.2), 0.1, -0.05])
    wrong = Pose(true.alpha + error[0], true.beta + error[1], true.dx_mm + error[2],
                 true.dy_mm + error[3])
    nodes = np.array([[100.0, 50.0], [600.0, 120.0], [1200.0, 200.0]])
    g = node_jacobian(CAMERA, wrong, PipeSection(R), grid, nodes)
    # Ground truth: where the wrong strip's node really is on the wall, found by
    # projecting it with the wrong pose and locating that pixel in the true strip.
    mx_t, my_t = unwrap_maps(CAMERA, true, PipeSection(R), grid)
    mx_w, my_w = unwrap_maps(CAMERA, wrong, PipeSection(R), grid)
    for (r, c), gn in zip(nodes.astype(int), g, strict=True):
        px = np.array([mx_w[r, c], my_w[r, c]])
        d = np.hypot(mx_t - px[0], my_t - px[1])
        rr, cc = np.unravel_index(np.argmin(d), d.shape)
        predicted = np.array([r, c]) + gn @ error
        assert np.allclose(predicted, [rr, cc], atol=1.0)


def test_pair_jacobians_are_each_pairs_own_with_one_call_a_frame() -> None:
    """The Jacobians of a chain of pairs, each frame asked once with all its nodes, are
    those of node_jacobian called pair by pair (oval section, tilted poses)."""
    grid = WallGrid.window(R, 0.135, 5.0, 40.0)
    rng = np.random.default_rng(4)
    poses = {f: Pose.from_degrees(*rng.uniform(-2, 2, 2), *rng.uniform(-3, 3, 2))
             for f in range(5)}
    section = PipeSection(R + 0.4, R - 0.4, np.deg2rad(30.0))
    pairs = [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4)]
    observations = [PatchShifts(i, j, rng.uniform([0, 0], [1500, 300], (n, 2)).astype(np.float32),
                                rng.normal(0, 3, (n, 2)).astype(np.float32), np.ones(n, np.float32))
                    for (i, j), n in zip(pairs, (7, 1, 12, 5, 9), strict=True)]
    asked = []

    def frame_jacobian(frame: int, nodes: np.ndarray) -> np.ndarray:
        asked.append(frame)
        return node_jacobian(CAMERA, poses[frame], section, grid, nodes)

    found = pair_jacobians(observations, frame_jacobian)
    assert sorted(asked) == list(range(5))
    for o, (g_i, g_j) in zip(observations, found, strict=True):
        for g, frame, nodes in ((g_i, o.i, o.nodes + o.shift), (g_j, o.j, o.nodes)):
            alone = node_jacobian(CAMERA, poses[frame], section, grid, nodes)
            # the same to rounding: numpy's matrix product of one row (a 1-patch pair
            # alone) rounds otherwise than of many (~1e-12 relative here)
            np.testing.assert_allclose(g, alone, rtol=1e-10, atol=1e-10)


def test_held_frames_keep_their_poses_and_still_measure_the_others() -> None:
    """Patch shifts exactly consistent with known pose errors, where the held frames'
    errors are 0: the held frames come out at exactly 0, the free ones at their
    errors, and every pair's rigid motion as made; the windowed solve agrees."""
    rng = np.random.default_rng(3)
    n = 12
    truth = rng.normal(0, [2e-3, 2e-3, 0.05, 0.05], (n, 4))
    held = {0, 2, 5, 6, 9}
    truth[sorted(held)] = 0.0
    observations, jacobians, rigid = [], {}, {}
    for i in range(n):
        for j in (i + 1, i + 2):
            if j < n:
                g_i, g_j = rng.normal(0, 40, (2, 30, 2, 4))
                rigid[(i, j)] = rng.normal(0, 30, 2)
                shift = rigid[(i, j)] + g_j @ truth[j] - g_i @ truth[i]
                observations.append(PatchShifts(i, j, rng.uniform(0, 500, (30, 2)), shift,
                                                np.full(30, 0.6)))
                jacobians[(i, j)] = (g_i, g_j)
    information = {f: np.diag([1e4, 1e4, 10.0, 10.0]) for f in range(n)}
    errors, motions = solve_pose_errors(observations, jacobians, information, held=held)
    for f in range(n):
        if f in held:
            assert np.all(errors[f] == 0.0)
        else:
            np.testing.assert_allclose(errors[f], truth[f], atol=1e-4)
    for key, motion in motions.items():
        np.testing.assert_allclose(motion, rigid[key], atol=1e-3)
    # in overlapping windows of 5 frames (1 of margin): the same, to far below the errors
    windowed, _ = solve_in_windows(observations, _given(jacobians),
                                   information, held=held, window=5, margin=1)
    for f in range(n):
        if f in held:
            assert np.all(windowed[f] == 0.0)
        np.testing.assert_allclose(windowed[f], errors[f], atol=1e-5)


def _banded(a: np.ndarray, width: int) -> np.ndarray:
    """``a`` in the lower banded form of scipy.linalg.cholesky_banded."""
    return np.array([np.concatenate([np.diag(a, -d), np.zeros(d)]) for d in range(width + 1)])


@pytest.mark.parametrize("n,width", [(1, 0), (9, 0), (12, 3), (60, 11)])
def test_inverse_in_band_is_the_inverse_within_the_band(n: int, width: int) -> None:
    rng = np.random.default_rng(n + width)
    a = np.zeros((n, n))
    for d in range(width + 1):
        v = rng.normal(size=n - d)
        a += np.diag(v, -d) + (np.diag(v, d) if d else 0.0)
    a += np.eye(n) * (np.abs(a).sum(axis=1).max() + 0.5)   # diagonally dominant: SPD
    found = _inverse_in_band(_banded(a, width))
    inv = np.linalg.inv(a)
    for d in range(width + 1):
        np.testing.assert_allclose(found[:n - d, d], np.diag(inv, d), rtol=1e-10, atol=1e-14)
    a[n // 2, n // 2] = -1.0   # not positive definite
    with pytest.raises(np.linalg.LinAlgError):
        _inverse_in_band(_banded(a, width))


def _noisy_chain(rng: np.random.Generator, truth: np.ndarray, noise: float,
                 jac: dict) -> list[PatchShifts]:
    """Patch shifts of a chain of frames (each linked to the next two), with Gaussian
    noise ``noise`` times the refinement's shift model (``SHIFT_SIGMA_PX`` at the
    patches' response)."""
    out = []
    response = np.full(30, 0.5)
    for (i, j), (g_i, g_j) in jac.items():
        sigma = SHIFT_SIGMA_PX / np.sqrt(response)[:, None]
        shift = g_j @ truth[j] - g_i @ truth[i] + rng.normal(0, noise, (30, 2)) * sigma
        out.append(PatchShifts(i, j, np.zeros((30, 2)), shift, response))
    return out


@pytest.mark.parametrize("noise", [3.0, 0.3])
def test_pose_covariances_match_the_scatter_of_the_solution(noise: float) -> None:
    """Solved again and again from shifts with fresh noise, the pose errors scatter as the
    stated covariance says when the shifts are noisier than the model (the variance
    factor scales it), and no more than it says when they are cleaner (the model's
    noise is the floor)."""
    rng = np.random.default_rng(7)
    n = 8
    jac = {(i, j): tuple(rng.normal(0, 40, (2, 30, 2, 4)))
           for i in range(n) for j in (i + 1, i + 2) if j < n}
    information = {f: np.diag([1e3, 1e3, 1.0, 1.0]) for f in range(n)}
    truth = np.zeros((n, 4))
    found, stated = [], []
    for _ in range(300):
        covariances: dict[int, np.ndarray] = {}
        errors, _ = solve_pose_errors(_noisy_chain(rng, truth, noise, jac), jac, information,
                                      covariances=covariances)
        found.append([errors[f] for f in range(n)])
        stated.append([np.sqrt(np.diag(covariances[f])) for f in range(n)])
    scatter = np.std(np.array(found), axis=0)          # (n, 4)
    sigma = np.median(np.array(stated), axis=0)
    ratio = scatter / sigma
    if noise > 1:
        assert np.all((ratio > 0.8) & (ratio < 1.2)), ratio
    else:
        assert np.all(ratio < 0.5), ratio   # 0.3 of the model's noise: ~0.3

def test_windowed_covariances_are_each_core_frame_s_own() -> None:
    """In windows of 5 frames (1 of margin) each frame states its own covariance: at
    least the whole run's (a window holds less), at most 1.2 times it (measured 1.18),
    though the frames' priors differ by up to 64 times."""
    rng = np.random.default_rng(8)
    n = 8
    jac = {(i, j): tuple(rng.normal(0, 40, (2, 30, 2, 4)))
           for i in range(n) for j in (i + 1, i + 2) if j < n}
    information = {f: np.diag([1e3, 1e3, 1.0, 1.0]) * (f + 1) ** 2 for f in range(n)}
    shifts = _noisy_chain(rng, np.zeros((n, 4)), 0.3, jac)   # the model's floor: scale 1
    whole: dict[int, np.ndarray] = {}
    solve_pose_errors(shifts, jac, information, covariances=whole)
    windowed: dict[int, np.ndarray] = {}
    solve_in_windows(shifts, _given(jac), information, window=5, margin=1,
                     covariances=windowed)
    assert sorted(windowed) == list(range(n))
    for f in range(n):
        ratio = np.sqrt(np.diag(windowed[f]) / np.diag(whole[f]))
        assert np.all(ratio > 1 - 1e-9) and np.all(ratio < 1.2), (f, ratio)


def test_held_frames_get_no_covariance() -> None:
    rng = np.random.default_rng(5)
    n = 6
    jac = {(i, i + 1): tuple(rng.normal(0, 40, (2, 30, 2, 4))) for i in range(n - 1)}
    covariances: dict[int, np.ndarray] = {}
    solve_pose_errors(_noisy_chain(rng, np.zeros((n, 4)), 1.0, jac), jac,
                      {f: np.eye(4) for f in range(n)}, held={0, 3}, covariances=covariances)
    assert sorted(covariances) == [1, 2, 4, 5]
    for c in covariances.values():
        assert np.all(np.linalg.eigvalsh(c) > 0) and np.allclose(c, c.T)


def _normal_of(observations: list[PatchShifts], jac: dict, information: dict):
    """The normal matrix ``solve_pose_errors`` builds (model weights), and its pose count."""
    from pipestitch.mosaic import refine

    frames = sorted(information)
    col = {f: 4 * k for k, f in enumerate(frames)}
    pairs = refine._pair_rows(observations, jac, col)
    n_unknown = 4 * len(frames) + 2 * len(pairs)
    import scipy.sparse as sp

    fixed = (refine._prior_normal(information, frames, n_unknown)
             + sp.identity(n_unknown, format="coo") * 1e-9).tocoo()
    normal, _ = refine._normal_equations(pairs, [1.0 / p.sigma**2 for p in pairs], fixed,
                                         refine._normal_pattern(pairs, fixed))
    return normal, 4 * len(frames)


def test_pose_covariances_are_the_inverse_normal_s_blocks() -> None:
    """The 4 x 4 blocks the banded route gives are those of the dense inverse of the
    whole normal matrix (pairs' unknowns included): pairs spanning 1-3 frames, either
    order, priors full, diagonal or none; with no pairs at all, the priors' inverse."""
    from pipestitch.mosaic.refine import _pose_covariances

    rng = np.random.default_rng(11)
    n = 7
    jac = {(i, j): tuple(rng.normal(0, 40, (2, 30, 2, 4)))
           for i, j in [(0, 1), (2, 1), (1, 3), (3, 4), (2, 5), (5, 6), (6, 4)]}
    a = rng.normal(size=(4, 4))
    priors = [np.diag([1e3, 1e3, 1.0, 1.0]), a @ a.T + np.eye(4), None]
    information = {f: priors[f % 3] for f in range(n)}
    observations = _noisy_chain(rng, np.zeros((n, 4)), 1.0, jac)
    normal, n_pose = _normal_of(observations, jac, information)
    dense = np.linalg.inv(normal.toarray())
    found = _pose_covariances(normal, n_pose, 1.0, list(range(n)), [4 * f for f in range(n)])
    for f in range(n):
        np.testing.assert_allclose(found[f], dense[4 * f:4 * f + 4, 4 * f:4 * f + 4],
                                   rtol=1e-8, atol=1e-15)
    for info in (np.diag([4.0, 9.0, 1.0, 1.0]), None):   # no pairs: a band of width 0
        normal, n_pose = _normal_of([], {}, {0: info, 1: info, 2: info})
        found = _pose_covariances(normal, n_pose, 2.0, [0, 1, 2], [0, 4, 8])
        dense = 4.0 * np.linalg.inv(normal.toarray())
        for f in range(3):
            np.testing.assert_allclose(found[f], dense[4 * f:4 * f + 4, 4 * f:4 * f + 4])
    normal, n_pose = _normal_of(observations, jac, information)
    normal.data[0] = np.nan   # a NaN Jacobian entry (a ray off the wall): no covariance
    assert _pose_covariances(normal, n_pose, 1.0, [0], [0]) == {}


def test_a_prior_centred_off_the_start_is_the_start_moved_there() -> None:
    """``prior_errors`` m: a frame no patch reaches comes out at m (its strong prior
    against the weak one); with patches, the solution is that of strips unwrapped at the
    start moved by m (the patch shifts less the warp m makes) plus m, as the linear
    model says (pipeline/pair_timing.py relies on it), the held frames at 0."""
    rng = np.random.default_rng(5)
    n = 8
    information = {f: np.diag([1e6, 1e6, 1e3, 1e3]) for f in range(n)}
    centre = {f: rng.normal(0, [1e-3, 1e-3, 0.02, 0.02]) for f in range(n)}
    errors, _ = solve_pose_errors([], {}, information, prior_errors=centre)
    for f in range(n):
        np.testing.assert_allclose(errors[f], centre[f], rtol=1e-4, atol=1e-9)
    held = {3}
    moved_start = {f: (np.zeros(4) if f in held else centre[f]) for f in range(n)}
    observations, as_moved, jacobians = [], [], {}
    for i in range(n - 1):
        g_i, g_j = rng.normal(0, 40, (2, 30, 2, 4))
        nodes, shift = rng.uniform(0, 500, (30, 2)), rng.normal(0, 0.3, (30, 2))
        observations.append(PatchShifts(i, i + 1, nodes, shift, np.full(30, 0.6)))
        warp = g_j @ moved_start[i + 1] - g_i @ moved_start[i]
        as_moved.append(PatchShifts(i, i + 1, nodes, shift - warp, np.full(30, 0.6)))
        jacobians[(i, i + 1)] = (g_i, g_j)
    ours, _ = solve_pose_errors(observations, jacobians, information, prior_errors=centre,
                                held=held)
    there, _ = solve_pose_errors(as_moved, jacobians, information, held=held)
    windowed, _ = solve_in_windows(observations, _given(jacobians), information,
                                   prior_errors=centre, held=held, window=5, margin=1)
    windowed_there, _ = solve_in_windows(as_moved, _given(jacobians), information, held=held,
                                         window=5, margin=1)
    for f in range(n):
        np.testing.assert_allclose(ours[f], there[f] + moved_start[f], rtol=1e-6, atol=1e-10)
        np.testing.assert_allclose(windowed[f], windowed_there[f] + moved_start[f], rtol=1e-6,
                                   atol=1e-10)
    assert np.all(ours[3] == 0.0)


def _ring_chain(seed: int, n: int) -> tuple[np.random.Generator, dict, np.ndarray, dict]:
    """A chain of ``n`` frames (each linked to the next two, random Jacobians) whose rings
    measure the pose to 3e-4 rad and 0.01 mm: (rng, Jacobians, ring sigma, information)."""
    rng = np.random.default_rng(seed)
    jac = {(i, j): tuple(rng.normal(0, 40, (2, 30, 2, 4)))
           for i in range(n) for j in (i + 1, i + 2) if j < n}
    ring_sigma = np.array([3e-4, 3e-4, 0.01, 0.01])
    return rng, jac, ring_sigma, {f: np.diag(1.0 / ring_sigma**2) for f in range(n)}


@pytest.mark.parametrize("noise", [1.0, 3.0])
def test_prior_share_finds_how_far_the_priors_moved(noise: float) -> None:
    """Frames whose true errors are s times a direction (the LED frames taken a share s
    of a step on: pipeline/pair_timing.py) plus their rings' own errors (drawn from the
    priors' information), priors centred on 0: ``prior_share`` finds s from the patch
    shifts, scattering over fresh noise as its stated sigma says (shifts as noisy as
    the model), or less (noisier: the residuals' scale widens the priors' share too)."""
    n, share = 10, 0.4
    rng, jac, ring_sigma, information = _ring_chain(11, n)
    direction = {f: rng.normal(0, [3e-3, 3e-3, 0.05, 0.05]) for f in range(n)}
    found, stated = [], []
    for _ in range(300):
        truth = np.array([share * direction[f] + rng.normal(0, ring_sigma) for f in range(n)])
        s, sigma = prior_share(_noisy_chain(rng, truth, noise, jac), jac, information,
                               direction)
        found.append(s)
        stated.append(sigma)
    assert abs(np.mean(found) - share) < 4 * np.std(found) / np.sqrt(len(found))
    ratio = np.std(found) / np.median(stated)
    assert (0.8 < ratio < 1.2) if noise == 1.0 else ratio < 1.2, ratio
    assert np.median(stated) < 0.1   # the patches tell it well here


def test_prior_share_of_a_direction_that_moves_no_prior() -> None:
    rng = np.random.default_rng(12)
    jac = {(i, i + 1): tuple(rng.normal(0, 40, (2, 30, 2, 4))) for i in range(4)}
    information = {f: np.eye(4) * 1e3 for f in range(5)}
    observations = _noisy_chain(rng, np.zeros((5, 4)), 1.0, jac)
    share, sigma = prior_share(observations, jac, information, {f: np.zeros(4) for f in range(5)})
    assert share == 0.0 and sigma == np.inf


@pytest.mark.parametrize("per_step", [0.0, 1.0])
def test_patch_led_share_finds_none_on_a_run_taken_together(per_step: float) -> None:
    """Rings with their own errors along a track changing by ``per_step`` of them from
    pair to pair, LED frames taken with the laser frames: the share the patches find
    is 0 within its sigma (the step to the next ring as the direction, which holds the
    frame's own ring error, made it 0.45 and 0.21 here)."""
    n = 20
    rng, jac, ring_sigma, information = _ring_chain(21, n)
    found, significant = [], 0
    for _ in range(40):
        track = np.cumsum(rng.normal(0, per_step, (n, 4)), axis=0) * ring_sigma
        rings = track + rng.normal(0, 1, (n, 4)) * ring_sigma
        poses = {f: Pose(*rings[f]) for f in range(n)}
        share, sigma = patch_led_share(poses, information,
                                       _noisy_chain(rng, rings - track, 1.0, jac), jac)
        found.append(share)
        significant += abs(share) > 3 * sigma
    assert abs(np.mean(found)) < 3 * np.std(found) / np.sqrt(len(found)), np.mean(found)
    assert significant <= 4


def test_patch_led_share_finds_the_share_along_a_smooth_track() -> None:
    n, share = 20, 0.5
    rng, jac, ring_sigma, information = _ring_chain(22, n)
    t = np.arange(n + 1, dtype=float)[:, None]
    track = (10 * t + 0.05 * t**2) * ring_sigma * np.array([1.0, -0.7, 0.5, 1.2])
    found = []
    for _ in range(20):
        rings = track[:n] + rng.normal(0, 1, (n, 4)) * ring_sigma
        led = track[:n] + share * (track[1:] - track[:n])
        poses = {f: Pose(*rings[f]) for f in range(n)}
        found.append(patch_led_share(poses, information,
                                     _noisy_chain(rng, rings - led, 1.0, jac), jac)[0])
    assert abs(np.mean(found) - share) < 0.03, found


def test_prior_share_of_a_problem_that_cannot_be_solved() -> None:
    # a NaN in a Jacobian (a ray off the wall): the factorisation fails; no share, no raise
    rng = np.random.default_rng(13)
    jac = {(i, i + 1): tuple(rng.normal(0, 40, (2, 30, 2, 4))) for i in range(4)}
    jac[(1, 2)][0][3, 0, 0] = np.nan
    information = {f: np.eye(4) * 1e3 for f in range(5)}
    observations = _noisy_chain(rng, np.zeros((5, 4)), 1.0, jac)
    direction = {f: np.full(4, 1e-3) for f in range(5)}
    assert prior_share(observations, jac, information, direction) == (0.0, np.inf)
