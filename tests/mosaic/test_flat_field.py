"""The lens' fall-off learned from the run: from the ratios of overlapping frames on a
two-tone wall and across an exposure step, clipped pixels left out of the ratios and
the medians, and blended only where nothing else saw the wall."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.mosaic._flat_field_kernels import group_medians
from pipestitch.mosaic.flat_field import (
    CLIPPED_WEIGHT,
    MIN_PAIR_NODES,
    MIN_RING_NODES,
    FlatInput,
    RadialFlatField,
    clipped_level,
    flat_input,
    pair_ratios,
    radial_levels,
    unclipped_weight,
)

EDGES = np.linspace(0.0, 600.0, 97)
CENTRE = (0.0, 0.0)
ROWS, COLS, SHIFT = 64, 200, 15      # strip size and the motion between frames (nodes)


def _fall_off(radius: np.ndarray) -> np.ndarray:
    return 1 - 0.35 * (radius / 500.0) ** 2


def _radius() -> np.ndarray:
    """Image radius of every strip node (the same for every frame: the frame's own
    grid): an equidistant fisheye's, 400 px per radian of incidence, seeing a wall 30 mm
    from the axis at 10-110 mm ahead (columns), a little off-centre (rows)."""
    rows, cols = np.mgrid[0:ROWS, 0:COLS]
    wall_mm = 30.0 + 3.0 * np.sin(2 * np.pi * rows / ROWS)
    return 400.0 * np.arctan(wall_mm / (10.0 + 0.5 * cols))


def _two_tone_wall(rng: np.random.Generator, n_cols: int) -> np.ndarray:
    """Blocks of 0.15 and 0.85 (a chart): any statistic of the values follows the tone
    that fills a ring."""
    blocks = rng.random((ROWS // 8 + 1, n_cols // 8 + 1)) < 0.4
    return np.where(np.kron(blocks, np.ones((8, 8)))[:ROWS, :n_cols], 0.85, 0.15)


def _frames(exposures: list[float], seed: int = 3) -> list[FlatInput]:
    """Frames moving SHIFT nodes along the wall each, seen through the fall-off."""
    rng = np.random.default_rng(seed)
    wall = _two_tone_wall(rng, COLS + SHIFT * len(exposures))
    radius = _radius()
    ring = (np.searchsorted(EDGES, radius, side="right") - 1).astype(np.int16)
    noise = 1 + 0.01 * rng.standard_normal((len(exposures), ROWS, COLS))
    return [FlatInput(np.log(wall[:, k * SHIFT:k * SHIFT + COLS] * _fall_off(radius)
                             * exposure * noise[k]).astype(np.float32), ring)
            for k, exposure in enumerate(exposures)]


def _solved(frames: list[FlatInput]) -> RadialFlatField:
    pairs = [pair_ratios(frames[k - d], frames[k], (0.0, float(SHIFT * d)), (k - d, k))
             for k in range(1, len(frames)) for d in (1, 2) if k - d >= 0]
    flat = RadialFlatField.from_pairs(pairs, EDGES, CENTRE)
    assert flat is not None
    return flat


def _error(flat: RadialFlatField) -> float:
    """Largest relative error of the fall-off over the radii of 90 % of the nodes (the
    extremes are seen by few node pairs)."""
    radius = np.linspace(*np.percentile(_radius(), [5, 95]), 50)
    got = np.interp(radius, flat.radius_px, flat.level)
    true = _fall_off(radius)
    ratio = got / true
    return float(np.max(np.abs(ratio / np.median(ratio) - 1)))


def test_the_fall_off_comes_from_overlaps_whatever_the_wall_shows() -> None:
    flat = _solved(_frames([1.0] * 14))
    # 1 % of a mid-grey wall is ~1.3 levels of 8 bits, the mosaic's shading budget; a
    # fall-off of 35 % that was not found would be off by ~10 %.
    assert _error(flat) < 0.01
    # The median of each ring's values over the frames follows the chart's tones.
    levels = [radial_levels(f, len(EDGES) - 1) for f in _frames([1.0] * 14)]
    assert _error(RadialFlatField.from_levels(levels, EDGES, CENTRE)) > 0.05


def _input(values: np.ndarray, grey: np.ndarray | None = None) -> FlatInput:
    """The flat field's input of a strip of ``values`` (shading 1) that is its own frame
    (node (r, c) read at pixel (c, r)), or was read from ``grey`` at the same places."""
    ones = np.ones_like(values)
    map_y, map_x = np.mgrid[0:values.shape[0], 0:values.shape[1]].astype(np.float32)
    frame = values if grey is None else grey
    return flat_input(frame, values, ones, ones, map_x, map_y, CENTRE, EDGES)


def test_an_exposure_step_does_not_bend_the_fall_off() -> None:
    """The overlaps across the step are offset as a whole and left out of the solve."""
    flat = _solved(_frames([1.0] * 7 + [1.3] * 7))
    assert _error(flat) < 0.01


def test_too_few_overlaps_give_no_pairwise_solve() -> None:
    frames = _frames([1.0, 1.0])
    few = pair_ratios(frames[0], frames[1], (0.0, float(COLS - 4)), (0, 1))
    assert RadialFlatField.from_pairs([few], EDGES, CENTRE) is None


def test_clipped_nodes_sort_last_in_a_ring_median() -> None:
    """A ring with a third of its nodes clipped keeps its median; more than half: NaN.
    The strip here is its own frame (one node per pixel, on the image row of the
    centre), so a node reads a clipped pixel exactly where it is clipped."""
    rng = np.random.default_rng(1)
    values = rng.uniform(0.2, 0.6, (ROWS, COLS)).astype(np.float32)
    true = values.copy()
    true[::3] = 1.5                                # bright wall: its true values, above
    clipped = np.where(true >= 1.0, 1.0, true).astype(np.float32)   # full scale
    n = len(EDGES) - 1
    exact = radial_levels(_input(true, np.zeros_like(true)), n)   # nothing clipped
    got = radial_levels(_input(clipped), n)
    seen = np.isfinite(exact)
    assert seen.sum() > 10
    np.testing.assert_allclose(got[seen], exact[seen], rtol=1e-6)   # float32 exp/log
    assert not np.allclose(got[seen], radial_levels(_input(values), n)[seen])   # counted
    mostly = np.where(np.arange(ROWS)[:, None] % 3 == 0, values, 1.0).astype(np.float32)
    assert np.isnan(radial_levels(_input(mostly), n)).all()


def test_clipped_nodes_are_left_out_of_the_ratios() -> None:
    values = np.random.default_rng(6).uniform(0.4, 0.6, (ROWS, COLS)).astype(np.float32)
    bright = values.copy()
    bright[:, 100:] = 1.0
    ratios = pair_ratios(_input(values), _input(bright), (0.0, 0.0), (0, 1))
    assert len(ratios.count) and np.all(ratios.log_ratio == 0)


@pytest.mark.parametrize(("clipped_at", "full_scale"), [((10, 10), 1.0), ((40, 3), 1.0),
                                                       ((20, 30), 4095 / 65535)])
def test_a_node_reading_a_clipped_pixel_is_blended_only_where_nothing_else_is(
        clipped_at: tuple[int, int], full_scale: float) -> None:
    """The clipped pixels are the plateau at the frame's maximum, whatever it is (12-bit
    data in a 16-bit file clips at 4095 / 65535); a maximum held by one pixel is not."""
    rng = np.random.default_rng(5)
    grey = (full_scale * rng.uniform(0.3, 0.6, (50, 60))).astype(np.float32)
    row, col = clipped_at
    grey[row:row + 2, col:col + 2] = full_scale   # 4 pixels of 3000: a plateau
    map_y, map_x = np.mgrid[0:50, 0:60].astype(np.float32) + np.float32(0.25)
    weight = np.ones((50, 60), np.float32)
    out = unclipped_weight(grey, map_x, map_y, weight)
    # the level found once per frame (what a run passes in every later pass) is the same
    assert clipped_level(grey) == pytest.approx(full_scale, rel=1e-6)
    np.testing.assert_array_equal(
        unclipped_weight(grey, map_x, map_y, weight, clipped_level(grey)), out)
    touched = np.zeros((50, 60), bool)
    touched[row - 1:row + 2, col - 1:col + 2] = True   # bilinear: nodes reading the block
    np.testing.assert_array_equal(out[touched], np.float32(CLIPPED_WEIGHT))
    np.testing.assert_array_equal(out[~touched], 1.0)
    grey[row:row + 2, col:col + 2] = 0.5 * full_scale
    grey[row, col] = full_scale                      # the brightest pixel, alone
    assert unclipped_weight(grey, map_x, map_y, weight) is weight
    assert clipped_level(grey) is None
    assert unclipped_weight(grey, map_x, map_y, weight, None) is weight


def test_the_compiled_fall_off_is_numpys_interpolation() -> None:
    rng = np.random.default_rng(2)
    flat = RadialFlatField((300.5, 200.25), 0.5 * (EDGES[:-1] + EDGES[1:]),
                           rng.uniform(0.7, 1.2, len(EDGES) - 1))
    map_x = rng.uniform(-50, 1300, (40, 70)).astype(np.float32)
    map_y = rng.uniform(-50, 1100, (40, 70)).astype(np.float32)
    radius = np.hypot(map_x.astype(np.float64) - 300.5, map_y.astype(np.float64) - 200.25)
    want = np.interp(radius, flat.radius_px, flat.level)   # the ends held beyond
    np.testing.assert_allclose(flat.at(map_x, map_y), want, rtol=1e-6)   # float32 out
    # ... and to the bit the float64 expression it compiles (ring position, its whole
    # part, the linear weights; rounded to float32 once)
    ring_px = flat.radius_px[1] - flat.radius_px[0]
    dx, dy = map_x.astype(np.float64) - 300.5, map_y.astype(np.float64) - 200.25
    pos = np.clip(np.sqrt(dx * dx + dy * dy) / ring_px - 0.5, 0.0, len(flat.level) - 1.0)
    low = np.minimum(pos.astype(int), len(flat.level) - 2)
    frac = pos - low
    exact = (flat.level[low] * (1.0 - frac) + flat.level[low + 1] * frac).astype(np.float32)
    np.testing.assert_array_equal(flat.at(map_x, map_y), exact)
    # times a strip's shading in the same pass: the float32 product of the two arrays
    shading = rng.uniform(0.2, 1.5, map_x.shape).astype(np.float32)
    np.testing.assert_array_equal(flat.at(map_x, map_y, shading), shading * exact)


def test_each_nodes_ring_is_the_float32_hypot_of_its_offset() -> None:
    # The ring index as numpy computes it: np.hypot of the float32 offsets (C's hypotf:
    # float64, rounded once), times rings per pixel in float32, truncated; -1 outside.
    rng = np.random.default_rng(4)
    map_x = rng.uniform(-100, 1400, (50, 70)).astype(np.float32)
    map_y = rng.uniform(-100, 1200, (50, 70)).astype(np.float32)
    map_x[0, :3] = -1
    centre = (612.3, 511.9)
    values = np.ones(map_x.shape, np.float32)
    got = flat_input(np.zeros((4, 4), np.float32), values, values, values, map_x, map_y,
                     centre, EDGES, None).ring
    radius = np.hypot(map_x - np.float32(centre[0]), map_y - np.float32(centre[1]))
    ring = (radius * np.float32((len(EDGES) - 1) / EDGES[-1])).astype(np.int32)
    want = np.where((ring >= 0) & (ring < len(EDGES) - 1), ring, -1).astype(np.int16)
    np.testing.assert_array_equal(got, want)
    assert np.any(got == -1) and np.any(got >= 0)


def _strip_input(rng: np.random.Generator, shape: tuple[int, int],
                 n_rings: int = 12) -> FlatInput:
    """Rings with -1 (no data) and log ratios with NaN, +inf (clipped), -inf (black)."""
    ring = rng.integers(-1, n_rings, shape).astype(np.int16)
    log_albedo = rng.normal(0.0, 0.3, shape).astype(np.float32)
    special = rng.random(shape)
    log_albedo[special < 0.05] = np.nan
    log_albedo[(special >= 0.05) & (special < 0.08)] = np.inf
    log_albedo[(special >= 0.08) & (special < 0.1)] = -np.inf
    return FlatInput(log_albedo, ring)


@pytest.mark.parametrize("motion", [(0.0, 0.0), (5.4, 13.0), (-7.6, -21.2), (130.0, 3.0),
                                    (-3.0, 61.0), (2.0, -80.0)])
def test_the_overlaps_ratios_are_each_cells_median_of_its_node_pairs(
        motion: tuple[float, float]) -> None:
    """Rows wrapping either way, columns shifted either way (by up to the whole strip);
    against the node pairs taken by numpy indexing and each cell's median by sorting."""
    rng = np.random.default_rng(int(abs(motion[1])))
    # three rings: most (ring, ring) cells hold enough node pairs to be kept
    first, second = _strip_input(rng, (50, 61), 3), _strip_input(rng, (50, 61), 3)
    got = pair_ratios(first, second, motion, (3, 4))
    dr, dc = round(motion[0]), round(motion[1])
    rows2 = np.arange(0, 50, 4)
    cols2 = np.arange(max(0, -dc), min(61, 61 - dc), 2)
    r2, c2 = np.meshgrid(rows2, cols2, indexing="ij")
    r1, c1 = (r2 + dr) % 50, c2 + dc
    a, b = first.ring[r1, c1].ravel(), second.ring[r2, c2].ravel()
    with np.errstate(invalid="ignore"):
        y = (second.log_albedo[r2, c2] - first.log_albedo[r1, c1]).ravel()
    keep = (a >= 0) & (b >= 0) & np.isfinite(y)
    want = []
    cells = {(int(p), int(q)) for p, q in zip(a[keep], b[keep], strict=True)}
    for ring1, ring2 in sorted(cells):
        values = np.sort(y[keep & (a == ring1) & (b == ring2)])
        if values.size >= MIN_PAIR_NODES:
            want.append((ring1, ring2, values[values.size // 2], values.size))
    assert got.frames == (3, 4)
    assert want or cols2.size < 10   # only a sliver of common columns keeps no cell
    assert list(zip(got.ring_first.tolist(), got.ring_second.tolist(),
                    got.log_ratio.tolist(), got.count.tolist(), strict=True)) == [
        (p, q, float(m), n) for p, q, m, n in want]


def test_a_strips_ring_levels_are_each_rings_median() -> None:
    """Clipped (+inf) and black (-inf) nodes sort to the ends; a ring with too few
    nodes is NaN, one whose median is clipped too."""
    rng = np.random.default_rng(9)
    flat = _strip_input(rng, (120, 90))
    flat.log_albedo[flat.ring == 4] = np.inf   # all clipped
    got = radial_levels(flat, 14)
    ring, values = flat.ring[::4, ::2], flat.log_albedo[::4, ::2]
    for k in range(14):
        mine = np.sort(values[(ring == k) & ~np.isnan(values)])
        if mine.size < MIN_RING_NODES or not np.isfinite(mine[mine.size // 2]):
            assert np.isnan(got[k]), k
        else:
            assert got[k] == np.exp(mine[mine.size // 2]), k


def test_group_medians_select_the_upper_middle_value_among_ties() -> None:
    # few distinct values (many equal to the pivot), the infinities, groups of 1 to 60
    # values and gaps between the groups present
    rng = np.random.default_rng(12)
    levels = np.array([-np.inf, -1.5, 0.0, 0.25, 0.25, 2.0, np.inf], np.float32)
    group = np.repeat(np.arange(0, 240, 4), rng.integers(1, 61, 60))
    rng.shuffle(group)
    value = rng.choice(levels, group.size)
    groups, counts, medians = group_medians(group, value)
    present = np.unique(group)
    np.testing.assert_array_equal(groups, present)
    for g, n, m in zip(groups, counts, medians, strict=True):
        mine = np.sort(value[group == g])
        assert (n, m) == (mine.size, mine[mine.size // 2])
    assert [a.size for a in group_medians(np.zeros(0, np.int64),
                                          np.zeros(0, np.float32))] == [0, 0, 0]


def test_strips_of_different_grids_are_refused() -> None:
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="one grid"):
        pair_ratios(_strip_input(rng, (40, 30)), _strip_input(rng, (40, 31)), (0.0, 0.0),
                    (0, 1))
