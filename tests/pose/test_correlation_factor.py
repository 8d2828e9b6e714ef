"""The ring residuals' correlation along the ring widens the reported uncertainty
(pose/_fit_kernels.correlation_factor): the effective sample size of a correlated series."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.pose._fit_kernels import correlation_factor

N = 1440   # rays around the ring
PHI = 2 * np.pi * np.arange(N) / N
U, V = 32.5 * np.cos(PHI), 32.5 * np.sin(PHI)


def _ar1(rho: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    e = rng.normal(size=N)
    x = np.empty(N)
    x[0] = e[0]
    for i in range(1, N):
        x[i] = rho * x[i - 1] + np.sqrt(1 - rho**2) * e[i]
    return x


def test_independent_residuals_keep_their_count() -> None:
    factors = [correlation_factor(np.random.default_rng(s).normal(size=N), U, V)
               for s in range(20)]
    assert np.median(factors) < 1.05 and max(factors) < 1.3


@pytest.mark.parametrize("rho", [0.5, 0.8])
def test_a_correlated_ring_counts_fewer(rho: float) -> None:
    # an AR(1) series' variance of the mean is (1 + rho) / (1 - rho) times the white one's
    expected = (1 + rho) / (1 - rho)
    factors = [correlation_factor(_ar1(rho, s), U, V) for s in range(20)]
    assert np.median(factors) == pytest.approx(expected, rel=0.15)


def test_a_long_correlation_is_counted_short() -> None:
    # rho 0.95 (39 times): the sum stops where the lags fall below significance and the
    # ring's low harmonics, which such a series is rich in, are removed first: ~0.7 of it
    factors = [correlation_factor(_ar1(0.95, s), U, V) for s in range(20)]
    assert 0.6 * 39 < np.median(factors) < 39


def test_a_section_the_model_does_not_hold_is_not_counted() -> None:
    # an oval fitted as a circle: a cos 2 theta residual, orthogonal to the pose
    rng = np.random.default_rng(1)
    oval = 0.05 * np.cos(2 * PHI + 0.3) + 0.01 * rng.normal(size=N)
    assert correlation_factor(oval, U, V) < 1.3


def test_too_few_or_constant_residuals() -> None:
    assert correlation_factor(np.arange(5.0), U[:5], V[:5]) == 1.0
    assert correlation_factor(np.zeros(100), U[:100], V[:100]) == 1.0
