"""Blending strips into the canvas: placement, seams across theta = 0, gain, release in
blocks, overview, vignetting.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from pipestitch.geometry import WallGrid
from pipestitch.mosaic.blend import Canvas, Overview, frame_grid, shade
from pipestitch.mosaic.unwrap import Strip

R = 32.5


def test_frame_grid_places_frames_by_z_and_roll() -> None:
    canvas_grid = WallGrid(radius_mm=R, deg_per_px=0.5,
                           mm_per_px_axial=0.1, z0_mm=-10.0, n_cols=1000)
    grid, col = frame_grid(canvas_grid, 12.34, 2.0, (-5.0, 30.0))
    assert grid.theta0_deg == -2.0
    assert canvas_grid.z0_mm + col * 0.1 - 12.34 == pytest.approx(grid.z0_mm)
    assert grid.z0_mm >= -5.0 and grid.z0_mm + (grid.n_cols - 1) * 0.1 <= 30.0


def test_canvas_blends_seamlessly_across_theta_zero_and_compensates_gain(texture) -> None:
    grid = WallGrid(radius_mm=R, deg_per_px=1.0, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=120)
    canvas = Canvas(grid)
    wall = texture((360, 120), seed=5)
    ones = np.ones((360, 80), np.float32)
    canvas.add(Strip(wall[:, :80].copy(), ones, ones), 0)
    gain = canvas.add(Strip(2.0 * wall[:, 40:120], ones, ones), 40)
    image, weights = canvas.image()
    assert np.all(weights > 0)
    assert gain == pytest.approx(0.5, rel=0.02)
    assert np.allclose(image, wall, atol=0.02)
    # A strip of quality 1 everywhere is weighed by its feather alone.
    feather = shade(Strip(wall[:, :80].copy(), ones, ones)).weight
    assert feather[0, 40] == 1.0 and feather[-1, 40] == 1.0   # rows wrap: no seam at 0/360
    assert feather[100, 0] < 0.1


@pytest.mark.parametrize("exposure", [0.97, 1.04, 0.8, 1.25])
def test_an_exposure_step_is_matched_and_a_small_offset_is_not(texture,
                                                               exposure: float) -> None:
    """A strip brighter or darker than the canvas by more than GAIN_DEADBAND (an
    exposure step) is matched to it; by less, it is blended as it is, so that the small
    bias each strip's ratio carries does not add up along the run into a drift."""
    from pipestitch.mosaic.blend import GAIN_DEADBAND

    grid = WallGrid(radius_mm=R, deg_per_px=1.0, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=120)
    canvas = Canvas(grid)
    wall = texture((360, 120), seed=6)
    ones = np.ones((360, 80), np.float32)
    canvas.add(Strip(wall[:, :80].copy(), ones, ones), 0)
    gain = canvas.add(Strip(exposure * wall[:, 40:120], ones, ones), 40)
    if abs(exposure - 1) <= GAIN_DEADBAND:
        assert gain == 1.0
    else:
        assert gain == pytest.approx(1 / exposure, rel=1e-3)


def test_canvas_released_in_blocks_equals_the_whole_canvas(texture) -> None:
    """Streaming: columns released as soon as no later strip reaches them give exactly
    the mosaic of a canvas held whole, and the window stays the width of the strips."""
    grid = WallGrid(radius_mm=R, deg_per_px=1.0, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=2000)
    wall = texture((360, 2000), seed=7)
    ones = np.ones((360, 300), np.float32)
    starts = list(range(0, 1701, 100))
    whole, streamed = Canvas(grid), Canvas(grid)
    blocks, widest = [], 0
    for k, c in enumerate(starts):
        strip = Strip((1 + 0.1 * (k % 3)) * wall[:, c:c + 300], ones, ones)
        whole.add(strip, c)
        streamed.add(strip, c)
        widest = max(widest, streamed.total.shape[1])
        nxt = starts[k + 1] if k + 1 < len(starts) else None
        got = streamed.release(nxt)
        if got is not None:
            blocks.append(got)
    image, weights = whole.image()
    firsts, mosaics, block_weights = zip(*blocks, strict=True)
    assert list(firsts) == starts      # released up to the next strip each time
    assert np.array_equal(np.concatenate(mosaics, axis=1), image, equal_nan=True)
    assert np.array_equal(np.concatenate(block_weights, axis=1), weights)
    assert widest <= 300 + 512
    with pytest.raises(ValueError, match="released"):
        streamed.add(Strip(wall[:, :300], ones, ones), 0)


def test_overview_keeps_the_wall_image_convention() -> None:
    """A reduced mosaic.png: row i at theta = i x its deg_per_px, column j at its z0 +
    j x its mm_per_px_axial, values the local mean; half-seen groups are data, others 0."""
    grid = WallGrid(radius_mm=R, deg_per_px=360 / 1500,
                    mm_per_px_axial=0.135, z0_mm=-12.0, n_cols=5003)
    theta = np.arange(1500)[:, None] * grid.deg_per_px
    z = grid.z0_mm + np.arange(5003)[None, :] * grid.mm_per_px_axial
    image = np.rint(128 + 60 * np.sin(np.deg2rad(theta)) + 0.1 * z).astype(np.uint8)
    image[:, 4000:4003] = 0                       # three unseen columns
    ov = Overview(grid, max_pixels=1_000_000)
    for c in range(0, 5003, 700):
        ov.push(image[:, c:c + 700])
    out = ov.finish()
    f, g = ov.factor, ov.grid
    assert f == 3 and out.shape == (g.n_rows, g.n_cols) == (500, 1668)
    th = np.arange(g.n_rows)[:, None] * g.deg_per_px
    zz = g.z0_mm + np.arange(g.n_cols)[None, :] * g.mm_per_px_axial
    expect = 128 + 60 * np.sin(np.deg2rad(th)) + 0.1 * zz
    data = out > 0
    assert np.abs(out[data] - np.broadcast_to(expect, out.shape)[data]).max() <= 1.01
    assert not data[:, 4000 // 3].any() and data[:, 4003 // 3 + 1].all()


_OVERVIEW_DIGEST = """
import hashlib, sys
import numpy as np
from pipestitch.geometry import WallGrid
from pipestitch.mosaic.blend import Overview
grid = WallGrid(radius_mm=30.0, deg_per_px=360 / 1513, mm_per_px_axial=0.1, z0_mm=0.0,
                n_cols=2400)
image = np.clip(np.random.default_rng(5).normal(128, 40, (1513, 2400)), 1, 255).astype(np.uint8)
ov = Overview(grid, max_pixels=1_000_000)
start = 0
for w in [int(v) for v in sys.argv[1].split(",")]:
    ov.push(image[:, start:start + w])
    start += w
print(hashlib.sha256(ov.finish().tobytes()).hexdigest())
"""


def test_the_overview_is_the_same_whatever_the_threads_and_blocks() -> None:
    """mosaic.png's reduced pixels are summed in one order: the same bits with one BLAS
    thread or two and with the mosaic pushed in blocks of other widths (a dense matrix
    product's blocking, and so its last bits, followed the threads BLAS had: a pixel
    here and there one grey level off between two runs of the same dataset)."""
    digests = set()
    for threads, widths in (("1", "2400"), ("2", "2400"), ("2", "1,2,3,700,999,695")):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        done = subprocess.run([sys.executable, "-c", _OVERVIEW_DIGEST, widths], env=env,
                              capture_output=True, text=True, check=True)
        digests.add(done.stdout.strip())
    assert len(digests) == 1


def test_a_long_run_samples_at_most_profile_frames_frames_evenly() -> None:
    from pipestitch.mosaic import blend as mosaic

    for n in (1, 499, 500, 501, 3000, 4001):
        step = mosaic.profile_step(n)
        assert len(range(0, n, step)) <= mosaic.PROFILE_FRAMES
        assert step == 1 or len(range(0, n, step - 1)) > mosaic.PROFILE_FRAMES   # no sparser


def test_a_strip_over_black_canvas_is_blended_at_gain_one(texture) -> None:
    """Over a canvas that holds 0 (a frame that saw no light, placed by the odometer),
    there is no exposure ratio to match: gain 1, no error."""
    grid = WallGrid(radius_mm=R, deg_per_px=1.0, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=120)
    canvas = Canvas(grid)
    ones = np.ones((360, 80), np.float32)
    canvas.add(Strip(np.zeros((360, 80), np.float32), ones, ones), 0)
    wall = texture((360, 120), seed=8)
    assert canvas.add(Strip(wall[:, 40:120].copy(), ones, ones), 40) == 1.0
