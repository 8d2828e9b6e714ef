"""Memory that must not grow with the run's length (issue 8): what is kept per frame,
and the working memory of the one solve over all frames (the photometric pose
refinement). Measured as bytes (tracemalloc, numpy's nbytes), never as RSS or time,
so the checks are exact and cheap."""

from __future__ import annotations

import dataclasses
import itertools
import sys
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from pipestitch.mosaic.refine import (
    SHIFT_SIGMA_PX,
    PatchShifts,
    _prior_root,
    refinement_windows,
    solve_in_windows,
    solve_pose_errors,
)

PATCHES = 34        # patch shifts per link on the mosaic's grid (measured: 34 on average)


def _given(jacobians: dict) -> Callable[[list[PatchShifts]], list]:
    """``solve_in_windows``' ``jacobians_of`` over Jacobians given by pair."""
    return lambda new: [jacobians[(o.i, o.j)] for o in new]


def _chain(n_frames: int, seed: int = 0) -> tuple[list[PatchShifts], dict, dict, np.ndarray]:
    """Patch shifts of a run linked to its next two frames, exactly consistent with
    known pose errors ``truth`` (n_frames, 4) and a rigid shift per link."""
    rng = np.random.default_rng(seed)
    truth = rng.normal(0, [2e-3, 2e-3, 0.05, 0.05], (n_frames, 4))
    observations, jacobians = [], {}
    for i in range(n_frames):
        for j in (i + 1, i + 2):
            if j >= n_frames:
                continue
            g_i = rng.normal(0, 40, (PATCHES, 2, 4))
            g_j = rng.normal(0, 40, (PATCHES, 2, 4))
            rigid = rng.normal(0, 30, 2)
            shift = rigid + g_j @ truth[j] - g_i @ truth[i]
            nodes = rng.uniform(0, 500, (PATCHES, 2))
            observations.append(PatchShifts(i, j, nodes, shift, np.full(PATCHES, 0.6)))
            jacobians[(i, j)] = (g_i, g_j)
    information = {f: np.diag([1e4, 1e4, 10.0, 10.0]) for f in range(n_frames)}
    return observations, jacobians, information, truth


def _dense_reference(observations, jacobians, information) -> np.ndarray:
    """The same weighted least squares (no reweighting needed: the data are exact)
    by a dense solve of the stacked rows."""
    n = len(information)
    n_unknown = 4 * n + 2 * len(observations)
    rows, rhs, sigma = [], [], []
    for k, o in enumerate(observations):
        g_i, g_j = jacobians[(o.i, o.j)]
        for p in range(len(o.nodes)):
            for axis in range(2):
                a = np.zeros(n_unknown)
                a[4 * n + 2 * k + axis] = 1.0
                a[4 * o.j:4 * o.j + 4] += g_j[p, axis]
                a[4 * o.i:4 * o.i + 4] -= g_i[p, axis]
                rows.append(a)
                rhs.append(o.shift[p, axis])
                sigma.append(SHIFT_SIGMA_PX / np.sqrt(o.response[p]))
    for f in range(n):
        root = _prior_root(information[f])
        for r in range(4):
            a = np.zeros(n_unknown)
            a[4 * f:4 * f + 4] = root[r]
            rows.append(a)
            rhs.append(0.0)
            sigma.append(1.0)
    a, b, s = np.array(rows), np.array(rhs), np.array(sigma)
    w = 1.0 / s**2
    normal = a.T @ (a * w[:, None]) + 1e-9 * np.eye(n_unknown)
    return np.linalg.solve(normal, a.T @ (w * b))


def test_pose_error_solve_matches_a_dense_solve_of_the_same_rows() -> None:
    observations, jacobians, information, truth = _chain(8)
    errors, motions = solve_pose_errors(observations, jacobians, information)
    x = _dense_reference(observations, jacobians, information)
    found = np.array([errors[f] for f in range(8)])
    np.testing.assert_allclose(found, x[:32].reshape(8, 4), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(found, truth, atol=1e-4)   # exact data, weak priors
    for k, o in enumerate(observations):
        np.testing.assert_allclose(motions[(o.i, o.j)], x[32 + 2 * k:34 + 2 * k], rtol=1e-9,
                                   atol=1e-9)


def _solve_peak_bytes(n_frames: int) -> int:
    args = _chain(n_frames)[:3]
    tracemalloc.start()
    try:
        solve_pose_errors(*args)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_pose_error_solve_working_memory_per_frame_is_small() -> None:
    """The solve's working memory beyond its inputs: ~12 kB a frame (a 10 x 10 block,
    the weights and the sparse normal matrix per link). Built as one sparse matrix with
    a row per patch shift from Python lists, it was ~170 kB a frame (670 MB at 4000
    pairs)."""
    per_frame = (_solve_peak_bytes(240) - _solve_peak_bytes(60)) / 180
    assert per_frame < 20_000, f"{per_frame:.0f} bytes a frame"


@pytest.mark.parametrize(("n", "window", "margin"), [(1000, 600, 100), (600, 600, 100),
                                                    (601, 600, 100), (37, 10, 2), (0, 10, 2)])
def test_refinement_windows_tile_the_run(n: int, window: int, margin: int) -> None:
    windows = refinement_windows(n, window, margin)
    cores = [(c0, c1) for _, _, c0, c1 in windows]
    assert cores[0][0] == 0 and cores[-1][1] == n
    assert all(a[1] == b[0] for a, b in itertools.pairwise(cores))
    for lo, hi, c0, c1 in windows:
        assert hi - lo <= window and lo <= c0 <= c1 <= hi
        assert c0 - lo == min(c0, margin) and (hi - c1 == margin or hi == n)
    assert len(windows) == 1 or n > window
    with pytest.raises(ValueError, match="margin"):
        refinement_windows(n, 2 * margin, margin)


def _noisy_chain(n_frames: int, seed: int = 1) -> tuple[list[PatchShifts], dict, dict]:
    """:func:`_chain` with patch-shift noise at its stated sigma and a few outliers."""
    observations, jacobians, information, _ = _chain(n_frames, seed)
    rng = np.random.default_rng(seed + 100)
    noisy = []
    for o in observations:
        shift = o.shift + rng.normal(0, SHIFT_SIGMA_PX / np.sqrt(0.6), o.shift.shape)
        shift[rng.random(len(shift)) < 0.03] += 5.0
        noisy.append(dataclasses.replace(o, shift=shift))
    return noisy, jacobians, information


def test_windowed_solve_is_the_whole_runs_solve() -> None:
    """In windows of 60 frames (20 of margin) the pose errors are the one solve's to a
    small fraction of their uncertainty, the motions too; one window is the one solve
    exactly; each pair's Jacobians are asked for once."""
    observations, jacobians, information = _noisy_chain(200)
    whole_e, whole_m = solve_pose_errors(observations, jacobians, information)
    asked = []

    def jacobians_of(new: list[PatchShifts]) -> list[tuple[np.ndarray, np.ndarray]]:
        asked.extend((o.i, o.j) for o in new)
        return [jacobians[(o.i, o.j)] for o in new]

    e, m = solve_in_windows(observations, jacobians_of, information, window=60, margin=20)
    assert sorted(asked) == sorted(jacobians) and len(set(asked)) == len(asked)
    assert set(e) == set(whole_e) and set(m) == set(whole_m)
    diff = np.array([e[f] - whole_e[f] for f in whole_e])
    spread = np.array(list(whole_e.values())).std(axis=0)
    assert np.all(np.abs(diff).max(axis=0) < 0.01 * spread), np.abs(diff).max(axis=0) / spread
    assert max(np.abs(m[k] - whole_m[k]).max() for k in whole_m) < 0.01
    one_e, one_m = solve_in_windows(observations, _given(jacobians),
                                    information, window=600, margin=100)
    assert all(np.array_equal(one_e[f], whole_e[f]) for f in whole_e)
    assert all(np.array_equal(one_m[k], whole_m[k]) for k in whole_m)


def test_windowed_solve_keeps_a_pair_reaching_back_past_the_margin() -> None:
    """A link across more frames than a window's margin (frames between it unread)
    widens its window: its motion and the frames' errors are still solved."""
    observations, jacobians, information, truth = _chain(120, seed=5)
    rng = np.random.default_rng(9)
    g_i, g_j = rng.normal(0, 40, (PATCHES, 2, 4)), rng.normal(0, 40, (PATCHES, 2, 4))
    rigid = np.array([3.0, -4.0])
    shift = rigid + g_j @ truth[70] - g_i @ truth[40]
    observations.append(PatchShifts(40, 70, rng.uniform(0, 500, (PATCHES, 2)), shift,
                                    np.full(PATCHES, 0.6)))
    jacobians[(40, 70)] = (g_i, g_j)
    e, m = solve_in_windows(observations, _given(jacobians), information,
                            window=40, margin=8)
    assert (40, 70) in m
    np.testing.assert_allclose(m[(40, 70)], rigid, atol=1e-3)
    assert len(e) == 120 and len(m) == len(observations)


def test_windowed_solve_working_memory_does_not_grow_with_the_run() -> None:
    """Beyond its result (an error per frame, a motion per pair: ~0.5 kB a frame), the
    windowed solve's working memory is one window's, at any length."""
    working = []
    for n in (240, 720):
        observations, jacobians, information, _ = _chain(n)
        tracemalloc.start()
        try:
            result = solve_in_windows(observations, _given(jacobians),
                                      information, window=120, margin=20)
            kept, peak = tracemalloc.get_traced_memory()
            working.append(peak - kept)
        finally:
            tracemalloc.stop()
        assert len(result[0]) == n
    assert working[1] < 1.1 * working[0], working


def _nbytes(obj: object, seen: set[int]) -> int:
    """Bytes held by ``obj`` through dataclass fields, containers and arrays."""
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes + (_nbytes(obj.base, seen) if obj.base is not None else 0)
    size = sys.getsizeof(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        size += sum(_nbytes(getattr(obj, f.name), seen) for f in dataclasses.fields(obj))
    elif isinstance(obj, dict):
        size += sum(_nbytes(k, seen) + _nbytes(v, seen) for k, v in obj.items())
    elif isinstance(obj, list | tuple | set):
        size += sum(_nbytes(v, seen) for v in obj)
    return size


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory, simulate_small) -> Path:
    """A 6-pair half-size dataset, simulated once for this module."""
    return simulate_small(tmp_path_factory.mktemp("mem") / "ds", "--pairs", "6", "--seed", "3")


@pytest.fixture(scope="module")
def summary(tmp_path_factory: pytest.TempPathFactory, small_run: Path):
    from pipestitch.pipeline.run import run_dataset

    return run_dataset(small_run, tmp_path_factory.mktemp("mem") / "out", show_progress=False,
                       led_cache_mb=0)


def test_the_views_kept_for_the_whole_run_are_compact(summary) -> None:
    """Per frame the stitch and the outputs keep the view (pose, section, information),
    not the ring points (the section refits are done), nor the refit's per-point
    residuals: ~1 kB a frame (was ~19 kB, then ~7 kB with the ring's plane
    coordinates)."""
    views = summary.mosaic.views
    assert len(views) == 6
    per_frame = _nbytes(views, set()) / len(views)
    assert per_frame < 2_500, f"{per_frame:.0f} bytes a frame"
    for view in views.values():
        assert view.ring is None
        assert view.alternative is None or view.alternative.ring is None
        assert view.measured is not None and view.measured.residuals_mm.size == 0


def test_links_and_positions_are_all_the_registration_keeps(summary) -> None:
    """The mosaic result holds links and positions, no patch shifts or column levels."""
    result = summary.mosaic
    per_frame = _nbytes([result.links, result.positions], set()) / len(result.views)
    assert per_frame < 2_000, f"{per_frame:.0f} bytes a frame"


def test_frames_no_longer_carry_their_rings_once_the_views_hold_them() -> None:
    from pipestitch.pipeline.posing import FramePose
    from pipestitch.pipeline.run import _without_rings
    from pipestitch.pose.fit import PoseFit, RingPoints

    ring = RingPoints(np.zeros((720, 2), np.float32), np.zeros((720, 2), np.float32), None)
    frames = [FramePose(0, PoseFit(True, "", ring=ring)), FramePose(1, PoseFit(False, "no ring"))]
    out = _without_rings(frames)
    assert out[0].fit.ring is None and out[0].fit.ok and out[1] is frames[1]


def test_a_pass_keeps_only_the_flat_field_data_of_the_sampled_frames(
        monkeypatch, tmp_path: Path, small_run: Path) -> None:
    """A registration pass keeps the ring levels and the overlap ratios of the frames the
    flat field samples (every profile_step-th frame), not every frame's: with at most
    2 profile frames, a 6-pair run keeps 2 frames' levels and at most their overlaps
    with the LINK_SPAN frames before each."""
    from pipestitch.mosaic import blend as mosaic
    from pipestitch.mosaic.flat_field import RadialFlatField
    from pipestitch.pipeline.run import run_dataset
    from pipestitch.pipeline.stitching import LINK_SPAN

    monkeypatch.setattr(mosaic, "PROFILE_FRAMES", 2)
    taken: dict[str, list] = {"levels": [], "pairs": []}
    from_levels, from_pairs = RadialFlatField.from_levels, RadialFlatField.from_pairs

    def spy_levels(levels, edges, centre):
        taken["levels"].append(list(levels))
        return from_levels(levels, edges, centre)

    def spy_pairs(pairs, edges, centre):
        taken["pairs"].append(list(pairs))
        assert from_pairs(pairs, edges, centre) is not None
        return None   # so that the levels are taken too

    monkeypatch.setattr(RadialFlatField, "from_levels", staticmethod(spy_levels))
    monkeypatch.setattr(RadialFlatField, "from_pairs", staticmethod(spy_pairs))
    run_dataset(small_run, tmp_path / "out", show_progress=False, led_cache_mb=0)
    assert taken["pairs"] and all(0 < len(p) <= 2 * LINK_SPAN for p in taken["pairs"])
    assert len({p.frames[1] for pairs in taken["pairs"] for p in pairs}) <= 2
    assert len(taken["levels"]) == len(taken["pairs"])
    assert all(len(levels) == 2 for levels in taken["levels"])
    assert all(lv.dtype == np.float32 for levels in taken["levels"] for lv in levels)
