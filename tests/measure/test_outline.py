"""A hole's rim along rays: on blurred discs, beside dark pits, on darkened walls."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.geometry import WallGrid
from pipestitch.measure.defects import find_defects
from pipestitch.measure.outline import rim_outline
from pipestitch.simulate.textures import Defect, draw_defects, make_wall


def _disc(shape: tuple[int, int], centre_rc: tuple[float, float], radius_mm: float,
          pitch: tuple[float, float], blur_px: float, supersample: int = 8) -> np.ndarray:
    """1 outside, 0.05 inside a disc of ``radius_mm`` (area-exact by supersampling),
    blurred by a Gaussian of ``blur_px``."""
    s = supersample
    rr, cc = np.mgrid[0:shape[0] * s, 0:shape[1] * s]
    y = ((rr + 0.5) / s - 0.5 - centre_rc[0]) * pitch[0]
    x = ((cc + 0.5) / s - 0.5 - centre_rc[1]) * pitch[1]
    hi = np.where(x * x + y * y < radius_mm**2, 0.05, 1.0)
    image = hi.reshape(shape[0], s, shape[1], s).mean(axis=(1, 3))
    return cv2.GaussianBlur(image, (0, 0), blur_px) if blur_px > 0 else image


@pytest.mark.parametrize("pitch,blur", [((0.135, 0.135), 1.5), ((0.1, 0.16), 2.5),
                                        ((0.07, 0.07), 0.0)])
def test_rim_of_a_blurred_disc_gives_its_area_and_centre(pitch, blur) -> None:
    shape = (round(12 / pitch[0]), round(12 / pitch[1]))
    centre = (shape[0] / 2 + 0.3, shape[1] / 2 - 0.3)
    image = _disc(shape, centre, 3.0, pitch, blur)
    rim = rim_outline(image, (centre[0] - 2, centre[1] + 1.5), 2.5, pitch)
    assert rim is not None
    assert rim.area_mm2 == pytest.approx(np.pi * 9.0, rel=0.01)
    assert rim.centre_row == pytest.approx(centre[0], abs=0.05)
    assert rim.centre_col == pytest.approx(centre[1], abs=0.05)


def test_a_dark_pit_touching_the_rim_does_not_grow_the_hole() -> None:
    pitch = (0.135, 0.135)
    image = _disc((120, 120), (60.0, 60.0), 3.0, pitch, 0.0)
    pit = _disc((120, 120), (60.0, 60.0 + 3.6 / 0.135), 1.0, pitch, 0.0)
    image = cv2.GaussianBlur(np.minimum(image, pit), (0, 0), 1.5)
    rim = rim_outline(image, (60.0, 60.0), 3.0, pitch)
    assert rim is not None and rim.outlier_fraction > 0.02
    assert rim.area_mm2 == pytest.approx(np.pi * 9.0, rel=0.015)


def test_hole_in_a_stain_is_sized_from_its_rim() -> None:
    """A 6 mm hole whose surroundings are 45 % darker on one side than the
    neighbourhood's median (a stain on a corroded wall): a fixed fraction of the depth
    sits off the rim there; the steepest step does not."""
    r = 32.5
    grid = WallGrid.square(r, 0.135, 0.0, 80.0)
    rng = np.random.default_rng(11)
    wall = make_wall("corrosion", grid, rng=rng)
    rows, cols = np.mgrid[0:grid.shape[0], 0:grid.shape[1]]
    row_c, col_c = 150.0 / grid.deg_per_px, 40.0 / grid.mm_per_px_axial
    dist = np.hypot(rows - row_c, cols - col_c - 20)
    stain = 1.0 - 0.45 * np.exp(-(dist / 30.0) ** 2)
    image = draw_defects(wall * stain, grid, [Defect("hole", 40.0, 150.0, 6.0)])
    image = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 1.2)
    found = find_defects(image, grid)
    holes = [d for d in found if d.kind == "hole"]
    assert len(holes) == 1
    assert holes[0].diameter_mm == pytest.approx(6.0, abs=0.05)
    assert holes[0].z_mm == pytest.approx(40.0, abs=0.05)


def test_no_rim_when_the_hole_leaves_the_image() -> None:
    image = _disc((40, 40), (20.0, 20.0), 3.0, (0.135, 0.135), 1.0)
    assert rim_outline(image, (2.0, 2.0), 3.0, (0.135, 0.135)) is None


@pytest.mark.parametrize("texture", ["aluminium", "corrosion"])
def test_a_dark_pit_is_a_spot_and_a_hole_is_a_hole(texture: str) -> None:
    """Both sharp and dark: the pit returns a fifth of the light of the wall around it,
    the hole (nearly) none, so only the hole is reported as one. The pit is a spot on
    plain aluminium; on corrosion, as dark as the texture's own darkest pits, it is
    below the detection threshold."""
    r = 32.5
    grid = WallGrid.square(r, 0.135, 0.0, 80.0)
    wall = make_wall(texture, grid, rng=np.random.default_rng(5))
    pit_cover = draw_defects(np.ones_like(wall), grid, [Defect("hole", 25.0, 60.0, 2.5)])
    pit_gain = 1.0 - 0.8 * (1.0 - pit_cover) / (1.0 - pit_cover.min())
    image = draw_defects(wall * pit_gain, grid, [Defect("hole", 55.0, 200.0, 2.5)])
    image = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 1.0)
    found = find_defects(image, grid)
    by_z = {round(d.z_mm): d for d in found}
    assert by_z[55].kind == "hole" and by_z[55].diameter_mm == pytest.approx(2.5, abs=0.05)
    if texture == "aluminium":
        assert by_z[25].kind == "spot"
        assert by_z[25].diameter_mm == pytest.approx(2.5, abs=0.1)
    else:
        assert 25 not in by_z
    assert len(found) == 2 if texture == "aluminium" else 1
