"""The mosaic score's axial scale and shading terms, on walls stretched and shaded here."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.geometry import WallGrid
from pipestitch.simulate.evaluate import WallImage, score_mosaic, truth_on_grid
from pipestitch.simulate.textures import make_wall

R = 32.5


@pytest.fixture(scope="module")
def truth() -> WallImage:
    grid = WallGrid.square(R, 0.07, 0.0, 200.0)
    wall = make_wall("corrosion", grid, rng=np.random.default_rng(2))
    return WallImage(image=wall, grid=grid)


def _mosaic(truth: WallImage, scale: float, shading: float = 0.0) -> WallImage:
    """The true wall as a mosaic whose z axis reads ``scale`` times the true z (0.14 mm
    per pixel), times a slow brightness ripple of relative amplitude ``shading``."""
    grid = WallGrid(radius_mm=R, deg_per_px=0.25, mm_per_px_axial=0.14, z0_mm=20.0,
                    n_cols=1200)
    # Mosaic node at mosaic z = (1 + e) * true z: sample the truth at z / (1 + e).
    image = truth_on_grid(truth, WallImage(image=np.zeros(grid.shape, np.float32), grid=grid),
                          0.0, 0.0)
    _, z_mosaic = grid.theta_z()
    cols = (z_mosaic / scale - grid.z0_mm) / grid.mm_per_px_axial
    image = np.stack([np.interp(cols, np.arange(image.shape[1]), row) for row in image])
    ripple = 1 + shading * np.sin(2 * np.pi * z_mosaic / 40.0)
    return WallImage(image=(image * ripple).astype(np.float32), grid=grid)


@pytest.mark.parametrize("error", [0.0, 0.002, -0.0015])
def test_axial_scale_error_is_measured_apart_from_the_local_geometry(truth, error) -> None:
    s = score_mosaic(_mosaic(truth, 1 + error), truth, 0.0, 0.0)
    assert s.axial_scale_error == pytest.approx(error, abs=1e-4)
    assert s.local_rms_mm < 0.02
    if error:
        assert s.geometric_rms_mm > 3 * s.local_rms_mm     # the stretch as "geometry"


def test_shading_left_in_the_mosaic_is_measured(truth) -> None:
    flat = score_mosaic(_mosaic(truth, 1.0), truth, 0.0, 0.0)
    shaded = score_mosaic(_mosaic(truth, 1.0, shading=0.1), truth, 0.0, 0.0)
    assert flat.shading_dn < 0.3
    # A +-10 % ripple of a wall whose mean is ~0.33 (85 levels): ~0.64 x 8.5 levels.
    assert 3.0 < shaded.shading_dn < 7.0


def test_an_image_off_its_grid_is_refused(truth) -> None:
    with pytest.raises(ValueError, match="shape"):
        WallImage(image=truth.image[:, :-1], grid=truth.grid)


def test_ssim_per_tenth_of_the_run_finds_the_damaged_tenth(truth) -> None:
    """A mosaic true everywhere but in its sixth tenth (columns 600-719 of 1200, noise of
    a third of the wall's range added): that tenth scores lowest, well below the
    others, and the whole run's mean hides most of it."""
    clean = _mosaic(truth, 1.0)
    image = clean.image.copy()
    rng = np.random.default_rng(0)
    image[:, 600:720] += rng.normal(0.0, 0.1, image[:, 600:720].shape).astype(np.float32)
    s = score_mosaic(WallImage(image=image, grid=clean.grid), truth, 0.0, 0.0)
    assert len(s.ssim_tenths) == 10
    assert int(np.argmin(s.ssim_tenths)) == 5
    others = np.delete(np.array(s.ssim_tenths), 5)
    assert s.ssim_worst_tenth == s.ssim_tenths[5]
    assert s.ssim_worst_tenth < others.min() - 0.2
    assert s.ssim_worst_tenth < s.ssim - 0.1
