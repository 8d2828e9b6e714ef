"""The wall each strip sees, from the rings of the run (mosaic/wall_profile.py)."""

from __future__ import annotations

import numpy as np

from pipestitch.mosaic.wall_profile import frame_profiles, ring_radius_noise

WINDOW = (-14.0, 34.0)   # each strip about its camera
AHEAD = 16.0             # the ring ahead of the camera


def _run(radius_at, n: int = 20, noise_mm: float = 0.01, seed: int = 0):
    rng = np.random.default_rng(seed)
    z = {i: 5.0 * i for i in range(n)}
    radius = {i: float(radius_at(z[i] + AHEAD) + rng.normal(0, noise_mm)) for i in z}
    return z, radius


def test_a_round_pipe_gives_no_profile_whatever_its_ring_noise() -> None:
    for noise in (0.002, 0.01, 0.05):
        for seed in range(5):
            z, radius = _run(lambda _: 32.5, noise_mm=noise, seed=seed)
            assert frame_profiles(z, radius, AHEAD, WINDOW, step_mm=0.07) == {}


def test_a_reducer_gives_the_strips_that_reach_it_the_wall_the_rings_measured() -> None:
    def wall(zz):   # 32.5 -> 30.5 mm between z 50 and 70
        return np.interp(zz, [50.0, 70.0], [32.5, 30.5])

    z, radius = _run(wall)
    profiles = frame_profiles(z, radius, AHEAD, WINDOW, step_mm=0.07)
    # the strips reaching z 50-70 mm: cameras from 50 - 34 = 16 to 70 + 14 = 84 mm
    reach = {i for i in z if z[i] + WINDOW[0] < 70 and z[i] + WINDOW[1] > 50}
    assert set(profiles) <= reach and len(profiles) >= len(reach) - 2
    worst = []
    for i, p in profiles.items():
        local = np.linspace(*WINDOW, 97)
        off = np.abs(p.at(local) * radius[i] - wall(z[i] + local))
        # straight between rings 5 mm apart: a corner of slope 0.1 is cut by 0.1 * 5 / 4;
        # the ring's own section alone is off by up to 2 mm there
        bound = 0.125 + 3 * 0.01
        assert np.max(off) < bound
        assert abs(p.at(AHEAD) - 1.0) < 1e-9                        # its own ring: itself
        worst.append(np.max(np.abs(radius[i] - wall(z[i] + local))))
    assert sum(w > 2 * bound for w in worst) >= 10


def test_a_standing_probe_merges_its_rings_and_few_rings_give_nothing() -> None:
    z = {0: 0.0, 1: 5.0, 2: 5.0, 3: 5.0, 4: 10.0, 5: 15.0, 6: 20.0}
    radius = {i: 32.5 for i in z}
    radius[6] = 31.0
    profiles = frame_profiles(z, radius, AHEAD, WINDOW, step_mm=0.07)
    assert all(np.all(np.diff(p.z_mm) > 0) for p in profiles.values())
    assert set(profiles) == {1, 2, 3, 4, 5, 6}   # frame 0's window ends at z 34 mm
    assert frame_profiles({0: 0.0, 1: 5.0, 2: 10.0}, {0: 32.5, 1: 32.5, 2: 30.0}, AHEAD,
                          WINDOW, step_mm=0.07) == {}


def test_ring_noise_ignores_the_few_rings_where_the_wall_turns() -> None:
    rng = np.random.default_rng(1)
    r = np.interp(np.arange(40.0), [15, 20], [32.5, 30.5]) + rng.normal(0, 0.01, 40)
    assert 0.006 < ring_radius_noise(r) < 0.016
    assert np.isnan(ring_radius_noise(r[:3]))
