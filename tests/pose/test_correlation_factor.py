"""The ring residuals' correlation along the ring widens the reported uncertainty
(pose/_fit_kernels.correlation_factor): the effective sample size of a correlated series."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.pose._fit_kernels import correlation_factor


def _ar1(rho: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    e = rng.normal(size=n)
    x = np.empty(n)
    x[0] = e[0]
    for i in range(1, n):
        x[i] = rho * x[i - 1] + np.sqrt(1 - rho**2) * e[i]
    return x


def test_independent_residuals_keep_their_count() -> None:
    factors = [correlation_factor(np.random.default_rng(s).normal(size=1440)) for s in range(20)]
    assert 0.95 < np.median(factors) < 1.1


@pytest.mark.parametrize("rho", [0.5, 0.8, 0.95])
def test_a_correlated_ring_counts_fewer(rho: float) -> None:
    # an AR(1) series' variance of the mean is (1 + rho) / (1 - rho) times the white one's
    expected = (1 + rho) / (1 - rho)
    factors = [correlation_factor(_ar1(rho, 1440, s)) for s in range(20)]
    assert np.median(factors) == pytest.approx(expected, rel=0.25)


def test_too_few_or_constant_residuals() -> None:
    assert correlation_factor(np.arange(5.0)) == 1.0
    assert correlation_factor(np.zeros(100)) == 1.0
