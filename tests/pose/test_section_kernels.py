"""The compiled section solve against ``scipy.optimize.least_squares`` on the same cost."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from pipestitch.geometry import PipeSection, Pose, laser_ring, rot_x, rot_y
from pipestitch.pose import section as section_module
from pipestitch.pose._section_kernels import fit_oval_offset
from pipestitch.pose.section import SECTION_BOUNDS, SECTION_X_SCALE, oval_jacobian, oval_residuals

D = 16.0


def _noisy_ring(a: float, b: float, dx: float, dy: float, ovality: float, angle: float,
                noise_mm: float, outliers: int, seed: int) -> np.ndarray:
    """Ring points of a simulated oval pipe with wall noise and stray points (a glint)."""
    rng = np.random.default_rng(seed)
    ring = laser_ring(Pose(a, b, dx, dy), PipeSection.oval(65.0, ovality, angle), D,
                      n_points=720)
    radial = ring[:, :2] / np.linalg.norm(ring[:, :2], axis=1)[:, None]
    ring[:, :2] += radial * rng.normal(0, noise_mm, (len(ring), 1))
    ring[:outliers, :2] += radial[:outliers] * rng.uniform(2, 6, (outliers, 1))
    return ring


def _scipy(points: np.ndarray, tilt: np.ndarray, x0: np.ndarray, noise_mm: float) -> np.ndarray:
    def fun(v: np.ndarray) -> np.ndarray:
        return oval_residuals(np.concatenate([tilt, v]), points)

    def jac(v: np.ndarray) -> np.ndarray:
        return oval_jacobian(np.concatenate([tilt, v]), points, tilt=False)

    return least_squares(fun, x0, jac=jac, loss="soft_l1", f_scale=noise_mm, method="trf",
                         x_scale=SECTION_X_SCALE, bounds=tuple(SECTION_BOUNDS),
                         xtol=1e-14, ftol=1e-14, gtol=1e-14).x


@settings(max_examples=40, deadline=None)
@given(a=st.floats(-0.06, 0.06), b=st.floats(-0.06, 0.06), dx=st.floats(-6, 6),
       dy=st.floats(-6, 6), ovality=st.floats(0.0, 0.1), angle=st.floats(0, np.pi),
       noise_mm=st.floats(0.005, 0.1), outliers=st.integers(0, 60), seed=st.integers(0, 99))
def test_the_compiled_solve_finds_scipys_minimum(a, b, dx, dy, ovality, angle, noise_mm,
                                                  outliers, seed) -> None:
    """Noisy rings with up to 8 % stray points, started a few mm and a circle off: the
    minimum scipy's solver finds (run to its tightest tolerances), to 1e-7 mm."""
    points = _noisy_ring(a, b, dx, dy, ovality, angle, noise_mm, outliers, seed)
    tilt = np.array([a, b])
    x0 = np.array([dx + 1.5, dy - 1.0, 31.0, 0.0, 0.0])
    rotated = np.ascontiguousarray(points @ (rot_x(a) @ rot_y(b))[:2].T)
    x, converged = fit_oval_offset(rotated, x0, noise_mm, SECTION_X_SCALE, SECTION_BOUNDS)
    assert converged
    want = _scipy(points, tilt, x0, noise_mm)
    np.testing.assert_allclose(x[:3], want[:3], rtol=0, atol=1e-7)      # dx, dy, r (mm)
    np.testing.assert_allclose(x[3:], want[3:], rtol=0, atol=1e-8)      # c, s


def test_a_solution_on_the_bounds_is_left_to_scipy(monkeypatch: pytest.MonkeyPatch) -> None:
    """An ovality beyond the model's bounds: the compiled solve reports no convergence
    and fit_section's answer is scipy's bounded one, on the bound."""
    points = _noisy_ring(0.0, 0.0, 1.0, -2.0, 0.9, 0.0, 0.01, 0, 3)   # c = 0.9 > 0.5
    rotated = np.ascontiguousarray(points[:, :2])
    x0 = np.array([0.0, 0.0, 30.0, 0.0, 0.0])
    _, converged = fit_oval_offset(rotated, x0, 0.01, SECTION_X_SCALE, SECTION_BOUNDS)
    assert not converged
    calls = []
    # fit_section imports it when it needs it (scipy.optimize is slow to import)
    monkeypatch.setattr(scipy.optimize, "least_squares",
                        lambda *a, **k: calls.append(1) or least_squares(*a, **k))
    fit = section_module.fit_section(points, Pose(0.0, 0.0, 0.0, 0.0), 30.0, noise_mm=0.01)
    assert calls and fit.section.ovality == pytest.approx(0.5, abs=1e-6)   # c on its bound


def test_non_finite_points_are_left_to_scipy() -> None:
    points = _noisy_ring(0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0, 1)
    points[5] = np.nan
    x0 = np.array([0.0, 0.0, 32.0, 0.0, 0.0])
    _, converged = fit_oval_offset(np.ascontiguousarray(points[:, :2]), x0, 0.01,
                                   SECTION_X_SCALE, SECTION_BOUNDS)
    assert not converged
