"""Registration of strips (axial shift and roll) and the global solve over the run's links."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipestitch.geometry import WallGrid
from pipestitch.mosaic.register import (
    Link,
    MotionPrior,
    measure_overlap_shift,
    measure_shift,
    odometer_noise_mm,
    registration_image,
    solve_positions,
    spectrum,
    strip_contrast,
)
from pipestitch.mosaic.unwrap import Strip

R = 32.5


def test_registration_recovers_axial_shift_and_roll(texture, shifted) -> None:
    grid = WallGrid(radius_mm=R, deg_per_px=360 / 720, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=300)
    wall = texture((720, 420))
    first = wall[:, :300]
    second = shifted(wall, 13.4, 37.3)[:, :300]     # frame j: 3.73 mm on, 6.7 deg of roll
    images = [registration_image(strip_contrast(Strip(s, np.ones_like(s), np.ones_like(s))),
                                 np.ones_like(s)) for s in (first, second)]
    link = measure_shift(images[0], images[1], grid, 0, 1)
    assert link is not None
    assert link.dz_mm == pytest.approx(3.73, abs=0.01)
    assert link.droll_deg == pytest.approx(13.4 * 0.5, abs=0.01)
    assert measure_shift(images[0], np.zeros_like(images[1]), grid, 0, 1) is None
    assert measure_shift(np.zeros_like(images[0]), images[1], grid, 0, 1) is None


def _one_value(shape: tuple[int, ...], at: tuple[int, ...], value: float,
               dtype: type) -> np.ndarray:
    image = np.zeros(shape, dtype)
    image[at] = value
    return image


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8])
def test_any_nonzero_is_numpy_any(dtype) -> None:
    """The emptiness test of measure_shift answers as numpy.any: every position (the
    last one too), views with strides, -0.0 (zero), NaN and the smallest subnormal
    (not zero), an empty image, and other dimensions than 2 (numpy's own path)."""
    from pipestitch.mosaic.register import _any_nonzero

    cases = [np.zeros((7, 5), dtype), np.zeros((0, 5), dtype)]
    cases += [_one_value((7, 5), (r, c), 3, dtype) for r in range(7) for c in range(5)]
    cases += [_one_value((8, 6), (1, 3), 1, dtype)[::2, ::2],    # the value left out
              _one_value((8, 6), (2, 4), 1, dtype)[::2, ::2],    # the value kept
              _one_value((8, 6), (2, 4), 1, dtype).T,
              _one_value((4,), (3,), 1, dtype), _one_value((3, 4, 2), (2, 3, 1), 1, dtype)]
    if np.issubdtype(dtype, np.floating):
        cases += [_one_value((7, 5), (6, 4), value, dtype)
                  for value in (-0.0, np.nan, np.finfo(dtype).smallest_subnormal, -np.inf)]
    for image in cases:
        assert _any_nonzero(image) == bool(np.any(image)), (image.shape, image.strides)


@pytest.mark.parametrize("shape", [(720, 300), (675, 300), (720, 243), (675, 243)])
def test_registration_with_a_motion_prior_on_strips_of_any_parity(shape: tuple[int, int],
                                                                  texture, shifted) -> None:
    # The correlation runs on packed spectra, whose layout depends on the parity of
    # both sizes; the prior (odometer-like, 0.3 mm and 0.5 deg off) must not bias it.
    n_rows, n_cols = shape
    grid = WallGrid(radius_mm=R, deg_per_px=360 / n_rows,
                    mm_per_px_axial=0.1, z0_mm=0.0, n_cols=n_cols)
    wall = texture((n_rows, n_cols + 120), seed=1)
    second = shifted(wall, 13.4, 37.3)[:, :n_cols]
    images = [registration_image(strip_contrast(Strip(s, np.ones_like(s), np.ones_like(s))),
                                 np.ones_like(s)) for s in (wall[:, :n_cols], second)]
    droll = 13.4 * grid.deg_per_px
    prior = MotionPrior(3.73 + 0.3, droll + 0.5, 3.0, 5.0)
    link = measure_shift(images[0], images[1], grid, 0, 1, prior,
                         (spectrum(images[0]), spectrum(images[1])))
    assert link is not None
    # One Lucas-Kanade step from the whole-pixel peak: ~0.02 px measured, 0.05 px allowed.
    assert link.dz_mm == pytest.approx(3.73, abs=0.005)
    assert link.droll_deg == pytest.approx(droll, abs=0.05 * grid.deg_per_px)


def test_a_large_step_is_measured_on_the_wall_both_strips_share(texture, shifted) -> None:
    # A step of 72 % of the strip: whole, the strips' common wall lies in the faint ends
    # of their tapers; cut to it (from the prior's expected step) it is all they compare.
    grid = WallGrid(radius_mm=R, deg_per_px=360 / 720, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=300)
    wall = texture((720, 540), seed=3)
    strips = [wall[:, :300], shifted(wall, 13.4, 217.3)[:, :300]]
    contrasts = [strip_contrast(Strip(s, np.ones_like(s), np.ones_like(s))) for s in strips]
    ones = np.ones_like(contrasts[0])
    droll = 13.4 * grid.deg_per_px
    prior = MotionPrior(21.73 + 0.8, droll - 0.5, 3.0, 5.0)   # an odometer 0.8 mm off
    whole = [registration_image(c, ones) for c in contrasts]
    assert measure_shift(*whole, grid, 0, 1, prior) is None   # no peak above MIN_RESPONSE
    link = measure_overlap_shift(contrasts[0], ones, contrasts[1], ones, grid, 0, 1, prior)
    assert link is not None and (link.i, link.j) == (0, 1)
    # one Lucas-Kanade step on a quarter of the strip: 0.06 px measured (four textures)
    assert link.dz_mm == pytest.approx(21.73, abs=0.1 * grid.mm_per_px_axial)
    assert link.droll_deg == pytest.approx(droll, abs=0.1 * grid.deg_per_px)
    far = MotionPrior(24.0, 0.0, 3.0, 5.0)   # less than a quarter of a strip in common
    assert measure_overlap_shift(contrasts[0], ones, contrasts[1], ones, grid, 0, 1, far) is None


def _link(i: int, j: int, dz: float, droll: float = 0.0) -> Link:
    return Link(i, j, dz, droll, 0.5, 0.02, 0.02)


def test_global_solve_outvotes_a_bad_link_and_an_odometer_slip() -> None:
    z_true = np.array([0.0, 5.1, 9.8, 15.2, 20.0, 25.3])
    roll_true = np.array([0.0, 0.3, 0.5, 0.6, 0.5, 0.2])
    links = [_link(i, j, z_true[j] - z_true[i], roll_true[j] - roll_true[i])
             for i in range(6) for j in (i + 1, i + 2) if j < 6]
    links[3] = dataclasses.replace(links[3], dz_mm=links[3].dz_mm + 4.0)   # a wrong peak
    odometer = {i: 1.02 * (z - 0.0) + 100.0 for i, z in enumerate(z_true)}
    odometer.update({k: v - 3.0 for k, v in odometer.items() if k >= 4})  # the wheel slips
    pos = solve_positions(6, links, odometry_mm=odometer)
    dz = np.diff(pos.z_mm)
    assert np.allclose(dz, np.diff(z_true), atol=0.01)
    assert np.allclose(pos.roll_deg - pos.roll_deg[0], roll_true, atol=0.01)
    assert (links[3].i, links[3].j, "registration") in pos.outliers
    assert any(src == "odometer" for *_, src in pos.outliers)


def test_roll_of_frames_tied_only_by_the_odometer_is_interpolated_and_reported() -> None:
    links = [_link(0, 1, 5.0, 10.0), _link(2, 3, 5.0, 10.0)]
    pos = solve_positions(4, links, odometry_mm={i: 5.0 * i for i in range(4)})
    assert np.allclose(np.diff(pos.z_mm), 5.0, atol=1e-6)
    assert pos.roll_deg[0] == pytest.approx(0.0, abs=1e-6)
    assert pos.roll_deg[1] == pytest.approx(10.0, abs=1e-3)
    assert pos.roll_deg[3] - pos.roll_deg[2] == pytest.approx(10.0, abs=1e-3)
    assert sorted(pos.roll_guessed) == [2, 3]


def test_a_frame_whose_only_links_are_rejected_is_not_placed() -> None:
    """Frame 4's two links disagree by 10 mm: neither can be trusted, so it is left out
    instead of being put somewhere in between."""
    good = [_link(0, 1, 5.0), _link(1, 2, 5.0), _link(0, 2, 10.0), _link(1, 3, 10.0),
            _link(2, 3, 5.0)]
    pos = solve_positions(5, [*good, _link(3, 4, 5.0), _link(2, 4, 20.0)])
    assert np.allclose(pos.z_mm[:4], [0.0, 5.0, 10.0, 15.0], atol=1e-6)
    assert np.isnan(pos.z_mm[4])
    assert {(3, 4, "registration"), (2, 4, "registration")} <= set(pos.outliers)


def test_global_solve_leaves_unconnected_frames_unplaced() -> None:
    links = [_link(0, 1, 5.0), _link(1, 2, 5.0), _link(3, 4, 5.0)]
    pos = solve_positions(5, links)
    assert np.all(np.isfinite(pos.z_mm[:3])) and np.all(np.isnan(pos.z_mm[3:]))
    pos = solve_positions(5, links, odometry_mm={i: 5.0 * i for i in range(5)})
    assert np.allclose(np.diff(pos.z_mm), 5.0, atol=1e-6)


def _run_with_odometer(noise_mm: float, step_mm: float, seed: int = 0) -> tuple[
        np.ndarray, list[Link], dict[int, float]]:
    """60 frames ~``step_mm`` apart linked to the next two (0.005 mm error, 0.02 mm
    sigma) and an odometer 3 % long whose increments have ``noise_mm`` of noise."""
    rng = np.random.default_rng(seed)
    z = np.cumsum(rng.normal(step_mm, 0.1 * step_mm, 60))
    links = [Link(i, j, z[j] - z[i] + rng.normal(0, 0.005), 0.0, 0.5, 0.02, 0.02)
             for i in range(60) for j in (i + 1, i + 2) if j < 60]
    odometer = 1.03 * z + np.cumsum(rng.normal(0, noise_mm, 60))
    return z, links, dict(enumerate(odometer))


def test_a_coarse_odometers_noise_is_measured_not_read_as_slips() -> None:
    """A cable counter with 2 mm of noise per 25 mm step (a 300 mm pipe's run): its
    sigma is measured from the increments the links measure too. At a fixed 0.5 mm,
    a quarter of its increments were reported as slips (beyond 3 sigma)."""
    z, links, odometer = _run_with_odometer(2.0, 25.0)
    # A robust (MAD) sigma of 59 increments is good to ~15 % (one standard error; 1.65 to
    # 2.46 mm over seeds 0-9): 30 % is two of them.
    assert odometer_noise_mm(links, odometer) == pytest.approx(2.0, rel=0.3)
    pos = solve_positions(60, links, odometry_mm=odometer)
    slips = [o for o in pos.outliers if o[2] == "odometer"]
    assert len(slips) <= 1
    assert np.allclose(np.diff(pos.z_mm), np.diff(z), atol=0.02)


def test_a_fine_odometers_slip_is_found() -> None:
    """An encoder with 0.02 mm of noise per 5 mm step slips by 1 mm once: twice a fixed
    0.5 mm sigma (kept, not reported), fifty times its measured one (reported)."""
    _, links, odometer = _run_with_odometer(0.02, 5.0, seed=1)
    odometer.update({k: v - 1.0 for k, v in odometer.items() if k >= 30})
    # Its 0.02 mm is measured (0.019 mm from the increments alone, 0.02 with the links'
    # sigma as the floor): far below it, the increments' noise was not measured.
    assert 0.01 < odometer_noise_mm(links, odometer) < 0.05
    pos = solve_positions(60, links, odometry_mm=odometer)
    assert [o for o in pos.outliers if o[2] == "odometer"] == [(29, 30, "odometer")]


def test_without_common_texture_the_odometers_noise_follows_its_step() -> None:
    assert odometer_noise_mm([], {i: 25.0 * i for i in range(10)}) == pytest.approx(2.5)


def test_an_encoder_coarser_than_the_frame_step_has_its_rounding_noise() -> None:
    """1 mm counts, frames 0.5 mm apart: increments of 0 and 1 count. Without the zero
    increments and the rounding noise (1 mm / sqrt(6) = 0.41 mm per increment) the
    counts looked noiseless (0.01 mm), half of them were reported as slips, and a
    stretch placed by the odometer alone came out at half its length."""
    rng = np.random.default_rng(3)
    z = np.arange(60) * 0.5
    links = [Link(i, j, z[j] - z[i] + rng.normal(0, 0.005), 0.0, 0.5, 0.01, 0.01)
             for i in range(60) for j in (i + 1, i + 2) if j < 60 and not 20 <= i < 40]
    odometer = {i: float(np.floor(v + 0.25)) for i, v in enumerate(z)}
    sigma = odometer_noise_mm(links, odometer)
    assert sigma == pytest.approx(1 / np.sqrt(6), rel=0.01)
    pos = solve_positions(60, links, odometry_mm=odometer)
    assert not [o for o in pos.outliers if o[2] == "odometer"]
    gap = pos.z_mm[40] - pos.z_mm[20]   # 10 mm bridged by the odometer alone
    assert gap == pytest.approx(10.0, abs=1.0)   # its counts know it to ~0.4 mm each end


def test_an_odometer_read_at_equal_steps_is_not_taken_for_a_coarse_counter() -> None:
    """A probe triggered every 5 mm of cable: equal increments, no rounding to infer."""
    _, links, _ = _run_with_odometer(0.0, 5.0)
    equal = {i: 5.0 * i for i in range(60)}
    # The true steps vary by 0.5 mm (a tenth of the step) where the readings do not: the
    # links see that much noise in the increments (0.51 mm measured).
    assert 0.25 < odometer_noise_mm(links, equal) < 1.0
