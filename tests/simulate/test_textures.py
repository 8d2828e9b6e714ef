"""Tests of the synthetic wall textures (pipestitch.simulate.textures).

Defects are measured independently of the drawing code: from the grid's own
pixel-centre coordinates (``WallGrid.theta_z``) and plain numpy, with the angle
difference wrapped here, not by the module.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipestitch.geometry import WallGrid
from pipestitch.simulate.textures import (
    DEFECT_KINDS,
    HOLE_ALBEDO,
    SPOT_FACTOR,
    TEXTURE_KINDS,
    Defect,
    aluminium_texture,
    chart_texture,
    corrosion_texture,
    draw_defects,
    make_wall,
    photo_texture,
    reference_test_piece,
)
from pipestitch.simulate.textures._texture_common import scale_wrapped

NOISE_KINDS = ("corrosion", "aluminium")


def _photo() -> np.ndarray:
    """A smooth-ish random grey 'photo' (uint8), deterministic."""
    rng = np.random.default_rng(123)
    img = cv2.GaussianBlur(rng.random((90, 120)).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min())
    return (img * 255).astype(np.uint8)


def _wall(kind: str, grid: WallGrid, seed: int = 5) -> np.ndarray:
    return make_wall(kind, grid, rng=np.random.default_rng(seed),
                     photo=_photo() if kind == "photo" else None, photo_tile_mm=7.0)


@pytest.fixture(scope="module")
def small_grid() -> WallGrid:
    return WallGrid.square(8.0, 0.08, 0.0, 30.0)


@pytest.fixture(scope="module")
def walls(small_grid: WallGrid) -> dict[str, np.ndarray]:
    return {kind: _wall(kind, small_grid) for kind in TEXTURE_KINDS}


def _row_steps(img: np.ndarray) -> tuple[np.ndarray, float]:
    """Mean |difference| between consecutive rows (interior) and across the wrap."""
    inner = np.abs(np.diff(img.astype(np.float64), axis=0)).mean(axis=1)
    wrap = float(np.abs(img[0].astype(np.float64) - img[-1]).mean())
    return inner, wrap


def _measure(cov: np.ndarray, grid: WallGrid, theta_c: float, z_c: float
             ) -> tuple[float, float, float]:
    """Area (mm²) and centroid offset (arc mm, z mm) of a coverage image from (theta_c, z_c)."""
    theta, z = grid.theta_z()
    dth = (theta - theta_c + 180.0) % 360.0 - 180.0
    ds = (grid.radius_mm * np.radians(dth))[:, None]
    dz = (z - z_c)[None, :]
    total = float(cov.sum())
    area = total * grid.mm_per_px_circ * grid.mm_per_px_axial
    return area, float((cov * ds).sum() / total), float((cov * dz).sum() / total)


# ------------------------------------------------------------------------- textures


@pytest.mark.parametrize("kind", TEXTURE_KINDS)
def test_shape_dtype_range(kind: str, walls: dict, small_grid: WallGrid) -> None:
    a = walls[kind]
    assert a.shape == small_grid.shape
    assert a.dtype == np.float32
    assert np.all(np.isfinite(a))
    assert a.min() >= 0.0 and a.max() <= 1.0
    assert a.std() > 0.005                     # not blank


@pytest.mark.parametrize("kind", TEXTURE_KINDS)
def test_deterministic(kind: str, walls: dict, small_grid: WallGrid) -> None:
    again = _wall(kind, small_grid, seed=5)
    assert np.array_equal(walls[kind], again)
    if kind != "photo":                        # the photo texture uses no randomness
        other = _wall(kind, small_grid, seed=6)
        assert not np.allclose(walls[kind], other)


def test_int_seed_same_as_generator(small_grid: WallGrid) -> None:
    assert np.array_equal(corrosion_texture(small_grid, 3),
                          corrosion_texture(small_grid, np.random.default_rng(3)))


@pytest.mark.parametrize("kind", [*NOISE_KINDS, "photo"])
def test_seamless_across_wrap(kind: str, walls: dict) -> None:
    """The step from the last row to row 0 looks like any other row step."""
    inner, wrap = _row_steps(walls[kind])
    lo, hi = np.quantile(inner, [0.001, 0.999])
    assert lo <= wrap <= hi, (kind, wrap, lo, hi)


@pytest.mark.parametrize("kind", NOISE_KINDS)
def test_seam_statistic_detects_a_cut(kind: str, small_grid: WallGrid) -> None:
    """Control: the same statistic flags a texture cut out of a longer turn."""
    g = small_grid
    longer = WallGrid(radius_mm=g.radius_mm, deg_per_px=360.0 / round(1.37 * g.n_rows),
                      mm_per_px_axial=g.mm_per_px_axial, z0_mm=g.z0_mm, n_cols=g.n_cols)
    img = make_wall(kind, longer, rng=np.random.default_rng(5))[:g.n_rows]
    inner, wrap = _row_steps(img)
    assert wrap > np.quantile(inner, 0.999)


def test_chart_seamless_across_wrap() -> None:
    """Row 0 starts a chart cell: the wrap step must look like the other cell boundaries.

    The grid puts every cell boundary on a pixel centre (125 rows per cell), so all
    boundaries are sampled alike and their row steps are comparable.
    """
    g = WallGrid(radius_mm=8.0, deg_per_px=360.0 / 625, mm_per_px_axial=0.08, z0_mm=0.0,
                 n_cols=376)
    assert round(2 * math.pi * g.radius_mm / 10.0) == 5    # 5 cells of 125 rows
    img = chart_texture(g, np.random.default_rng(5))
    inner, wrap = _row_steps(img)
    steps = [inner[125 * a - 1] for a in range(1, 5)]
    assert min(steps) * 0.85 <= wrap <= max(steps) * 1.15, (wrap, steps)
    # A cell boundary is not an ordinary row step: the test has something to see.
    assert np.median(inner) < 0.5 * min(steps)


def test_chart_contrast_and_structure_everywhere(walls: dict, small_grid: WallGrid) -> None:
    a = walls["chart"]
    assert np.quantile(a, 0.02) < 0.1 and np.quantile(a, 0.98) > 0.85
    # Every 8 mm x 8 mm block has strong structure, all round and along z.
    bs = round(8.0 / small_grid.mm_per_px_circ)
    bz = round(8.0 / small_grid.mm_per_px_axial)
    for i in range(0, a.shape[0] - bs + 1, bs // 2):
        for j in range(0, a.shape[1] - bz + 1, bz // 2):
            assert a[i:i + bs, j:j + bz].std() > 0.2, (i, j)


def test_chart_is_defined_in_mm() -> None:
    """The chart at 0.05 mm/px, filtered to 0.1 mm/px, matches the chart at 0.1 mm/px."""
    n = 628
    coarse = WallGrid(radius_mm=10.0, deg_per_px=360.0 / n, mm_per_px_axial=0.1, z0_mm=3.0,
                      n_cols=300)
    fine = WallGrid(radius_mm=10.0, deg_per_px=360.0 / (2 * n), mm_per_px_axial=0.05, z0_mm=3.0,
                    n_cols=599)
    c = chart_texture(coarse, np.random.default_rng(7))
    f = chart_texture(fine, np.random.default_rng(7))
    k = np.array([0.25, 0.5, 0.25], np.float32)
    # Fine pixel (2i, 2j) has the centre of coarse pixel (i, j); the [1 2 1]/4 filter
    # stands in for the coarse pixel's footprint.
    f2 = cv2.sepFilter2D(f, -1, k, k, borderType=cv2.BORDER_REFLECT)[::2, ::2]
    assert np.corrcoef(c.ravel(), f2.ravel())[0, 1] > 0.97
    assert np.abs(c - f2).mean() < 0.04


def test_aluminium_statistics() -> None:
    g = WallGrid.square(8.0, 0.04, 0.0, 30.0)
    a = aluminium_texture(g, np.random.default_rng(1))
    assert 0.68 < a.mean() < 0.72
    assert 0.008 < a.std() < 0.04              # a few per cent of 0.7
    x = a.astype(np.float64) - a.mean()

    def corr(lag_mm: float, axis: int) -> float:
        pitch = g.mm_per_px_axial if axis == 1 else g.mm_per_px_circ
        lag = round(lag_mm / pitch)
        y = np.roll(x, -lag, axis=axis)
        if axis == 1:                          # z is not periodic: drop the wrapped columns
            return float((x[:, :-lag] * y[:, :-lag]).mean() / x[:, :-lag].var())
        return float((x * y).mean() / x.var())

    # Streaks: long along z (brushing direction), short around.
    assert corr(0.2, 1) > 0.9
    assert corr(0.2, 0) < 0.75
    assert corr(1.0, 1) > corr(1.0, 0) + 0.3


def test_corrosion_statistics(walls: dict) -> None:
    a = walls["corrosion"]
    assert 0.2 < np.median(a) < 0.45
    assert a.std() > 0.05
    assert np.mean(a <= 0.0) < 1e-3 and np.mean(a >= 1.0) < 1e-3


def test_photo_scale_and_mirroring() -> None:
    """A photo that ramps 0 -> 1 left to right becomes a triangle wave of period 2 tiles."""
    ramp = np.tile(np.linspace(0, 255, 200), (50, 1)).astype(np.uint8)
    g = WallGrid.square(10.0, 0.05, 0.0, 40.0)
    tile = 12.0
    a = photo_texture(g, ramp, tile)
    _, z = g.theta_z()
    t = (z / tile) % 2.0
    expect = np.where(t < 1.0, t, 2.0 - t)
    inner = (np.abs(t - np.rint(t)) > 0.03)    # away from the folds, where it is rounded
    assert np.allclose(a[:, inner].mean(axis=0), expect[inner], atol=0.02)
    assert np.allclose(a, a[:1], atol=1e-5)    # the ramp is constant along theta
    with pytest.raises(ValueError):
        photo_texture(g, ramp, 0.0)
    for img in (ramp.astype(np.uint16) * 257, ramp / 255.0,
                np.dstack([ramp, ramp, ramp])):
        assert np.allclose(photo_texture(g, img, tile), a, atol=1e-3)


def test_make_wall_errors(small_grid: WallGrid) -> None:
    with pytest.raises(ValueError):
        make_wall("marble", small_grid, rng=np.random.default_rng(0))
    with pytest.raises(ValueError):
        make_wall("photo", small_grid, rng=np.random.default_rng(0))


def test_make_wall_draws_defects(small_grid: WallGrid) -> None:
    d = [Defect("hole", 15.0, 100.0, 3.0)]
    rng = np.random.default_rng(2)
    plain = aluminium_texture(small_grid, rng)
    walled = make_wall("aluminium", small_grid, rng=np.random.default_rng(2), defects=d)
    assert np.array_equal(walled, draw_defects(plain, small_grid, d))


# ------------------------------------------------------------------------- defects


@pytest.mark.parametrize(("radius", "pitch", "theta", "z", "diameter"), [
    (10.0, 0.05, 123.4, 14.7, 3.0),
    (10.0, 0.05, 0.3, 12.0, 3.0),            # straddles theta = 0
    (10.0, 0.05, 359.2, 20.0, 4.0),          # straddles theta = 0 from the other side
    (6.0, 0.07, 47.0, 9.93, 1.2),            # small: ~17 px across
])
def test_hole_area_and_centre(radius: float, pitch: float, theta: float, z: float,
                              diameter: float) -> None:
    g = WallGrid.square(radius, pitch, 0.0, 30.0)
    bg = 0.5
    a = draw_defects(np.full(g.shape, bg, np.float32), g, [Defect("hole", z, theta, diameter)])
    r = diameter / 2
    px_area = g.mm_per_px_circ * g.mm_per_px_axial
    half_diag = 0.5 * math.hypot(g.mm_per_px_circ, g.mm_per_px_axial)
    assert a.min() == pytest.approx(HOLE_ALBEDO, abs=1e-6)

    # Thresholded at half depth = pixels whose centre is inside the circle. Each such
    # pixel's square lies within the circle grown by half a pixel diagonal and every
    # pixel square inside the circle shrunk by it is counted, hence these exact bounds.
    dark = a < 0.5 * (bg + HOLE_ALBEDO)
    area_thr, cs, cz = _measure(dark.astype(np.float64), g, theta, z)
    assert math.pi * (r - half_diag) ** 2 <= area_thr <= math.pi * (r + half_diag) ** 2
    assert math.hypot(cs, cz) < 2 * half_diag

    # Coverage-weighted: the symmetric one-pixel ramp is unbiased to O(w²) (pi w²/12 =
    # 0.26 px); summing it at pixel spacing adds < 1.2 px of quadrature error (worst of
    # 400 random discs). Two pixels of tolerance, two-sided.
    cov = (bg - a.astype(np.float64)) / (bg - HOLE_ALBEDO)
    area, cs, cz = _measure(cov, g, theta, z)
    assert abs(area - math.pi * r * r) <= 2 * px_area
    # Centroid: measured < 0.02 px over the same discs.
    assert abs(cs) < 0.05 * g.mm_per_px_circ and abs(cz) < 0.05 * g.mm_per_px_axial

    # Sharp edge: the ramp is about one pixel wide.
    partial = (cov > 0.02) & (cov < 0.98)
    assert partial.sum() * px_area < 2.0 * (2 * math.pi * r) * pitch


def test_hole_across_wrap_is_whole() -> None:
    """A hole at theta = 0 has the same pixel pattern as a hole away from the wrap."""
    g = WallGrid(radius_mm=10.0, deg_per_px=360.0 / 1256, mm_per_px_axial=0.05, z0_mm=0.0,
                 n_cols=300)
    bg = np.full(g.shape, 0.5, np.float32)
    at0 = draw_defects(bg, g, [Defect("hole", 7.5, 0.0, 3.0)])
    at90 = draw_defects(bg, g, [Defect("hole", 7.5, 90.0, 3.0)])
    shifted = np.roll(at90, -round(90.0 / g.deg_per_px), axis=0)
    assert np.allclose(at0, shifted, atol=1e-5)
    assert (at0[:5] < 0.3).any() and (at0[-5:] < 0.3).any()


def test_spot() -> None:
    g = WallGrid.square(10.0, 0.05, 0.0, 30.0)
    bg = 0.6
    d = 4.0
    a = draw_defects(np.full(g.shape, bg, np.float32), g, [Defect("spot", 15.0, 200.0, d)])
    ratio = a.astype(np.float64) / bg
    assert ratio.min() == pytest.approx(SPOT_FACTOR, abs=1e-5)
    cov = (1.0 - ratio) / (1.0 - SPOT_FACTOR)
    area, cs, cz = _measure(cov, g, 200.0, 15.0)
    # Symmetric ramp, width hypot(pixel, 0.12 d): unbiased up to pi w²/12 ~ 0.06 mm².
    assert abs(area - math.pi * (d / 2) ** 2) < 0.1
    assert abs(cs) < 0.005 and abs(cz) < 0.005
    # Softer than a hole: the edge ramp is several pixels wide.
    partial = (cov > 0.02) & (cov < 0.98)
    assert partial.sum() * g.mm_per_px_circ * g.mm_per_px_axial > 0.3 * (math.pi * d) * 0.12 * d


def test_draw_defects_does_not_modify_input_and_checks_shape(small_grid: WallGrid) -> None:
    bg = np.full(small_grid.shape, 0.5, np.float32)
    out = draw_defects(bg, small_grid, [Defect("hole", 10.0, 10.0, 2.0)])
    assert np.all(bg == 0.5) and out is not bg
    with pytest.raises(ValueError):
        draw_defects(bg[:-1], small_grid, [])


@pytest.mark.parametrize("bad", [("crack", 0, 0, 1.0), ("hole", 0, 0, 0.0),
                                 ("spot", float("nan"), 0, 1.0)])
def test_defect_validation(bad: tuple) -> None:
    assert set(DEFECT_KINDS) == {"hole", "spot"}
    with pytest.raises(ValueError):
        Defect(*bad)


def test_reference_test_piece_layout() -> None:
    radius = 32.5
    holes = reference_test_piece(100.0, radius_mm=radius)
    assert len(holes) == 7
    assert all(h.kind == "hole" and h.diameter_mm == 6.0 for h in holes)
    centre = holes[0]
    assert (centre.z_mm, centre.theta_deg) == (100.0, 90.0)
    axial = sorted(h.z_mm for h in holes if h.theta_deg == 90.0)
    assert axial == pytest.approx([52.0, 76.0, 100.0, 124.0, 148.0])
    around = sorted(h.theta_deg for h in holes if h.theta_deg != 90.0)
    assert len(around) == 2
    arcs = [radius * math.radians(t - 90.0) for t in around]
    assert arcs == pytest.approx([-24.0, 24.0])
    # Wraps the angles into [0, 360).
    near0 = reference_test_piece(0.0, 0.0, radius_mm=radius)
    assert all(0.0 <= h.theta_deg < 360.0 for h in near0)


def test_reference_test_piece_drawn() -> None:
    """Seven separate holes, 24 mm apart, measured on the drawn image."""
    radius = 20.0
    g = WallGrid.square(radius, 0.2, 40.0, 160.0)
    holes = reference_test_piece(100.0, radius_mm=radius)
    a = draw_defects(np.full(g.shape, 0.5, np.float32), g, holes)
    mask = (a < 0.26).astype(np.uint8)
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    assert n - 1 == 7
    theta, z = g.theta_z()
    s = radius * np.radians(theta)
    cents = []
    for k in range(1, n):
        rows, cols = np.nonzero(labels == k)
        area = len(rows) * g.mm_per_px_circ * g.mm_per_px_axial
        assert area == pytest.approx(math.pi * 9.0, rel=0.08)
        cents.append((s[rows].mean(), z[cols].mean()))
    cents = np.array(cents)
    s0 = radius * math.radians(90.0)
    on_axis = np.abs(cents[:, 0] - s0) < 1.0
    assert on_axis.sum() == 5
    assert np.allclose(np.diff(np.sort(cents[on_axis, 1])), 24.0, atol=0.05)
    side = cents[~on_axis]
    assert np.allclose(np.sort(side[:, 0]) - s0, [-24.0, 24.0], atol=0.05)
    assert np.allclose(side[:, 1], 100.0, atol=0.05)


def test_wrapped_rescale_in_chunks_matches_one_warp() -> None:
    """Very long walls are rescaled in column chunks (OpenCV crashes on a 20 m wall):
    the chunks must join exactly as one wrapped warp would."""
    src = np.random.default_rng(0).standard_normal((50, 300)).astype(np.float32)
    m = np.array([[300 / 1000, 0, 0], [0, 50 / 200, 0]])
    one = cv2.warpAffine(src, m, (1000, 200), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_WRAP)
    # OpenCV rounds each warp's coordinates to fixed point from its own offset, so
    # values of up to 4 agree to 1.4e-4 (measured), not to the bit; a chunk joined one
    # source column off would be wrong by about the values themselves
    chunked = scale_wrapped(src, 200, 1000, chunk_cols=64)
    assert np.abs(chunked - one).max() < 1e-3


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc")
@pytest.mark.skipif((os.cpu_count() or 1) < 2,
                    reason="on one CPU a transform on every core is on one thread anyway")
def test_a_wall_is_made_without_starting_threads_a_fork_would_stop() -> None:
    """The simulator forks its renderers after making the wall: the wall's noise must
    not leave a native thread pool behind (pocketfft's stops its threads around each
    fork and could wait forever), so the process has as many threads after as before."""
    code = ("import os, numpy as np\n"
            "from pipestitch.simulate.textures._texture_common import filtered_noise\n"
            "def threads(): return len(os.listdir('/proc/self/task'))\n"
            "before = threads()\n"
            "noise = filtered_noise(np.random.default_rng(1), (256, 512), (0.2, 0.2),\n"
            "                       lambda fs, fz: 1.0 / (1.0 + fs * fs + fz * fz))\n"
            "assert noise.shape == (256, 512) and abs(float(noise.std()) - 1.0) < 1e-3\n"
            "print(before, threads())\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=False, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    before, after = map(int, proc.stdout.split())
    assert after == before
