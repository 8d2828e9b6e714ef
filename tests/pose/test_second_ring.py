"""The candidates a ring fit leaves: a second ring or nothing (pose/second_ring.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipestitch.pose.ring import RingDetection
from pipestitch.pose.second_ring import leftover_ring

CENTRE = np.array([612.0, 510.0])
N_AZ = 360


def _circle(radius_px: float, azimuths: np.ndarray) -> np.ndarray:
    phi = azimuths * (2 * np.pi / N_AZ)
    return CENTRE + radius_px * np.stack([np.cos(phi), np.sin(phi)], 1)


def _detection(*rings: tuple[float, np.ndarray]) -> RingDetection:
    """Candidates on circles of the given radii over the given rays, ranked in the order
    the rings are given (the first is every ray's strongest)."""
    pixels, azimuth, rank = [], [], []
    for k, (radius, rays) in enumerate(rings):
        pixels.append(_circle(radius, rays))
        azimuth.append(rays)
        rank.append(np.full(len(rays), k))
    pixels, azimuth, rank = (np.concatenate(a) for a in (pixels, azimuth, rank))
    order = np.lexsort((rank, azimuth))           # by ray, strongest first, as detect_ring
    rank = rank[order]
    # a ray the first ring misses has the second as its strongest
    for ray in np.unique(azimuth):
        on = azimuth[order] == ray
        rank[on] = np.arange(on.sum())
    return RingDetection(pixels=pixels[order], azimuth=azimuth[order], rank=rank,
                         snr=np.full(len(rank), 20.0), n_azimuths=N_AZ, noise=0.01,
                         line_sigma_px=1.0)


def test_a_second_ring_is_what_the_fitted_one_left() -> None:
    all_rays = np.arange(N_AZ)
    det = _detection((300.0, all_rays), (276.0, all_rays[::2]))
    rest = leftover_ring(det, _circle(300.0, all_rays[::3]), CENTRE, min_rays=N_AZ // 4)
    assert rest is not None
    radius = np.hypot(*(rest.pixels - CENTRE).T)
    np.testing.assert_allclose(radius, 276.0)
    assert np.array_equal(np.unique(rest.azimuth), all_rays[::2])
    assert np.all(rest.rank == 0)    # ranked again: each is now its ray's strongest


def test_the_fitted_ring_may_be_the_weaker_one() -> None:
    all_rays = np.arange(N_AZ)
    det = _detection((276.0, all_rays), (300.0, all_rays))   # the ghost ranks first
    rest = leftover_ring(det, _circle(300.0, all_rays), CENTRE, min_rays=N_AZ // 2)
    assert rest is not None
    np.testing.assert_allclose(np.hypot(*(rest.pixels - CENTRE).T), 276.0)


def test_scattered_leftovers_or_a_ring_alone_are_no_second_ring() -> None:
    all_rays = np.arange(N_AZ)
    alone = _detection((300.0, all_rays))
    assert leftover_ring(alone, _circle(300.0, all_rays), CENTRE, min_rays=10) is None
    glints = _detection((300.0, all_rays), (150.0, all_rays[:40]))
    assert leftover_ring(glints, _circle(300.0, all_rays), CENTRE, min_rays=N_AZ // 2) is None


def test_candidates_within_the_line_width_of_the_ring_are_the_ring() -> None:
    all_rays = np.arange(N_AZ)
    det = _detection((300.0, all_rays), (303.0, all_rays))   # 3 sigma off: the same line
    assert leftover_ring(det, _circle(300.0, all_rays), CENTRE, min_rays=10) is None


def test_a_ring_under_the_frames_relative_floor_is_a_second_ring() -> None:
    """A reflection 8x as strong as the ring sets the ring search's relative floor above
    the ring: the ring's maxima come as ``fainter``. They are the leftovers, kept by the
    same floor taken relative to their own strength; maxima under that go."""
    all_rays = np.arange(N_AZ)
    glow = replace(_detection((100.0, all_rays)), snr=np.full(N_AZ, 160.0))
    ring = _detection((300.0, all_rays), (340.0, all_rays[::2]))
    ring = replace(ring, rank=ring.rank + 1,                 # ranked after the glow's
                   snr=np.where(np.hypot(*(ring.pixels - CENTRE).T) < 320.0, 20.0, 3.0))
    det = replace(glow, fainter=ring, relative_floor=0.2)
    rest = leftover_ring(det, _circle(100.0, all_rays), CENTRE, min_rays=N_AZ // 2)
    assert rest is not None
    # the ring's candidates (20 > 0.2 x 20), not the weak ones at 340 px (3 < 4)
    np.testing.assert_allclose(np.hypot(*(rest.pixels - CENTRE).T), 300.0)
    assert np.array_equal(rest.azimuth, all_rays) and np.all(rest.rank == 0)
    # without them the glow's detection leaves nothing
    assert leftover_ring(replace(det, fainter=None), _circle(100.0, all_rays), CENTRE,
                         min_rays=N_AZ // 2) is None
