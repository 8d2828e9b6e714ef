"""The LED frame's shift against the laser frame along the ring's rays, on polar frames
built with a known shift: a wall texture, the LED frame that texture, the laser frame a
line whose brightness is the texture where the laser frame sees it."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from pipestitch.pose import pair_motion as pm
from pipestitch.pose.pair_motion import LedShift, led_shift

N_RAYS, N_SAMPLES, RING = 1440, 400, 180.0


def _wall(seed: int = 0, grain: float = 3.0) -> np.ndarray:
    """A wall texture on the polar grid: smoothed noise, positive, float32."""
    noise = np.random.default_rng(seed).normal(size=(N_RAYS, N_SAMPLES)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), grain)
    return np.exp(0.4 * smooth / smooth.std()).astype(np.float32)


def _pair(along: np.ndarray, across: np.ndarray, seed: int = 0, grain: float = 3.0
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(laser, led, rays, at): the LED frame is the wall; the laser frame sees at ray r,
    sample s the wall the LED frame shows at ray r + across[r], sample s + along[r]."""
    led = _wall(seed, grain)
    seen = LedShift(along, across).apply(led)
    rays = np.arange(N_RAYS)
    at = np.rint(RING + 6 * np.sin(rays * 2 * math.pi / N_RAYS)).astype(np.int64)
    samples = np.arange(N_SAMPLES)[None, :]
    line = np.exp(-0.5 * ((samples - at[:, None]) / 2.0) ** 2).astype(np.float32)
    return line * seen + np.float32(0.01), led, rays, at


def _measure(laser: np.ndarray, led: np.ndarray, rays: np.ndarray, at: np.ndarray):
    return led_shift(laser, led, rays, at, N_RAYS, max_shift=60,
                     samples_per_ray=2 * math.pi * RING / N_RAYS)


def test_a_shift_along_and_across_the_rays_is_measured() -> None:
    phi = np.arange(N_RAYS) * 2 * math.pi / N_RAYS
    along = 23.0 + 4.0 * np.cos(phi) - 2.5 * np.sin(phi)
    across = 1.5 - 1.0 * np.sin(phi)
    found = _measure(*_pair(along, across))
    assert found is not None
    assert np.max(np.abs(found.along - along)) < 0.5
    assert np.max(np.abs(found.across - across)) < 0.5


def test_a_shift_inward_is_measured() -> None:
    found = _measure(*_pair(np.full(N_RAYS, -11.0), np.zeros(N_RAYS), seed=3))
    assert found is not None
    assert np.max(np.abs(found.along + 11.0)) < 0.5
    assert np.max(np.abs(found.across)) < 0.5


def test_frames_taken_at_one_position_are_told_still() -> None:
    found = _measure(*_pair(np.zeros(N_RAYS), np.zeros(N_RAYS)))
    assert found is not None and not found.moved   # no shift, and the wall says so


def _uneven(laser: np.ndarray, strength: float, seed: int) -> np.ndarray:
    """The laser frame with its line's brightness varying along the ring by something
    other than the wall (the laser's own ripple, a dirty mirror): log-normal, smooth
    over a few rays."""
    ripple = np.random.default_rng(seed + 100).normal(size=(N_RAYS, 1)).astype(np.float32)
    ripple = cv2.GaussianBlur(ripple, (0, 0), 3.0)
    return laser * np.exp(strength * ripple / ripple.std()).astype(np.float32)


@pytest.mark.parametrize("seed", range(4))
def test_a_still_pair_with_an_uneven_line_is_told_still(seed: int) -> None:
    laser, led, rays, at = _pair(np.zeros(N_RAYS), np.zeros(N_RAYS), seed=seed, grain=8.0)
    found = _measure(_uneven(laser, 0.2, seed), led, rays, at)
    assert found is not None and not found.moved


@pytest.mark.parametrize("shift", [6.0, -6.0, 8.0, 12.0])
@pytest.mark.parametrize("strength", [0.2, 0.4])
def test_a_shift_the_ring_cannot_resolve_is_never_told_still(shift: float,
                                                              strength: float) -> None:
    # a coarse texture and an uneven line: the correlation's peak is as wide as the
    # shift and no shift may correlate about as well as the true one; the ring then
    # cannot tell, which is no evidence that the frames were taken together
    for seed in range(4):
        laser, led, rays, at = _pair(np.full(N_RAYS, shift), np.zeros(N_RAYS), seed=seed,
                                     grain=8.0)
        found = _measure(_uneven(laser, strength, seed), led, rays, at)
        assert found is None or found.moved, seed


def test_a_line_that_is_not_on_the_wall_gives_no_shift() -> None:
    # its brightness owes nothing to the wall the LED frame shows (a glowing mount)
    laser, _, rays, at = _pair(np.full(N_RAYS, 15.0), np.zeros(N_RAYS), seed=1)
    assert _measure(laser, _wall(seed=2), rays, at) is None


def test_a_wall_without_texture_gives_no_shift() -> None:
    laser, _, rays, at = _pair(np.full(N_RAYS, 15.0), np.zeros(N_RAYS))
    flat = np.ones((N_RAYS, N_SAMPLES), np.float32)
    rng = np.random.default_rng(4)
    noisy = (flat + rng.normal(0, 1e-3, flat.shape)).astype(np.float32)
    assert _measure(laser, noisy, rays, at) is None


def test_too_few_ring_rays_give_no_shift() -> None:
    laser, led, rays, at = _pair(np.full(N_RAYS, 15.0), np.zeros(N_RAYS))
    assert _measure(laser, led, rays[:20], at[:20]) is None


@pytest.mark.parametrize("across", [0.0, 2.25, -3.5])
def test_apply_reads_the_frame_where_the_shift_says(across: float) -> None:
    rows, cols = np.mgrid[0:N_RAYS, 0:N_SAMPLES].astype(np.float32)
    ramp = (cols + 1000.0 * rows).astype(np.float32)   # its own coordinates
    moved = LedShift.constant(N_RAYS, 7.25, across).apply(ramp)
    inner = (slice(10, N_RAYS - 10), slice(0, N_SAMPLES - 10))
    np.testing.assert_allclose(moved[inner], ramp[inner] + 7.25 + 1000.0 * across, atol=0.1)
    # rays wrap around: the first ray reads the last ones when turned back
    if across < 0:
        np.testing.assert_allclose(moved[0, 5], 5 + 7.25 + 1000.0 * (N_RAYS + across),
                                   atol=0.1)


@pytest.mark.parametrize(("shifts", "turns", "smooth"), [
    (np.arange(-3, 12), np.arange(-2, 3), 1),              # 15 shifts: blocks of 4 and 3
    (np.arange(-9, 10, 2), np.zeros(1, np.int64), pm.COARSE_SMOOTH),   # the coarse search
    (np.arange(-398, 400, 57), np.array([-1, 1439]), 1),   # clipped at both ends of a ray
    (np.arange(-5, 6), np.array([1437]), 1),               # one turn, wrapping around
])
def test_the_correlations_are_each_sectors_pearson_coefficient(
        shifts: np.ndarray, turns: np.ndarray, smooth: int) -> None:
    """Every sector, turn and shift at once against numpy's correlation coefficient of
    the same samples; a sector with too few rays is NaN."""
    laser, led, rays, at = _pair(np.full(N_RAYS, 9.0), np.zeros(N_RAYS), seed=5)
    keep = (rays < 700) | (rays % 97 == 0)   # sectors 4-7: a ray or two each, too few
    rays, at = rays[keep], at[keep]
    sectors = rays * pm.SECTORS // N_RAYS
    line = pm._brightness(laser, rays, at, smooth)
    got = pm._correlations(line, led, rays, at, sectors, shifts, turns, smooth)
    assert got.shape == (pm.SECTORS, turns.size, shifts.size)
    counts = np.bincount(sectors, minlength=pm.SECTORS)
    for k in range(pm.SECTORS):
        if counts[k] < pm.MIN_SECTOR_RAYS:
            assert np.all(np.isnan(got[k]))
            continue
        mine = sectors == k
        for i, turn in enumerate(turns):
            for j, shift in enumerate(shifts):
                wall = led[(rays + turn) % N_RAYS, np.clip(at + shift, 0, N_SAMPLES - 1)]
                wall = pm._high_pass(np.log(wall)[None, :], smooth)[0]   # the whole ring
                want = np.corrcoef(wall[mine], line[mine])[0, 1]
                assert got[k, i, j] == pytest.approx(want, abs=1e-6)
