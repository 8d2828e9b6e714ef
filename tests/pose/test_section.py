"""Oval sections from the ring: exact with the tilt known, and why the tilt must be known."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipestitch.geometry import PipeSection, Pose, laser_ring
from pipestitch.pose.section import (
    fit_section,
    oval_jacobian,
    oval_residuals,
    section_free_information,
)

D = 16.0


@settings(max_examples=30, deadline=None)
@given(a=st.floats(-0.08, 0.08), b=st.floats(-0.08, 0.08), dx=st.floats(-5, 5),
       dy=st.floats(-5, 5), ovality=st.floats(0.0, 0.08), angle=st.floats(0, np.pi))
def test_section_and_offset_are_exact_given_the_tilt(a, b, dx, dy, ovality, angle) -> None:
    section = PipeSection.oval(65.0, ovality, angle)
    pose = Pose(a, b, dx, dy)
    ring = laser_ring(pose, section, D, n_points=360)
    fit = fit_section(ring, Pose(a, b, 0.0, 0.0), 32.0)   # offset and radius start off
    assert fit.section.ovality == pytest.approx(ovality, abs=1e-7)
    assert fit.section.mean_radius_mm == pytest.approx(32.5, abs=1e-6)
    assert fit.pose.dx_mm == pytest.approx(dx, abs=1e-6)
    assert fit.pose.dy_mm == pytest.approx(dy, abs=1e-6)
    if ovality > 1e-3:   # the direction of the major axis (defined modulo 180°)
        diff = (fit.section.angle - angle) % np.pi
        assert min(diff, np.pi - diff) < 1e-4


def test_residual_is_the_radial_distance_to_first_order() -> None:
    section = PipeSection.oval(65.0, 0.05, 0.3)
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    on_wall = section.points(theta, 0.0)
    x = np.array([0, 0, 0, 0, 32.5, 0.05 * np.cos(0.6), 0.05 * np.sin(0.6)])
    np.testing.assert_allclose(oval_residuals(x, on_wall), 0.0, atol=1e-9)
    r_theta = section.radius_at(theta)
    inside = on_wall * np.column_stack([1 - 0.01 / r_theta, 1 - 0.01 / r_theta,
                                        np.ones_like(theta)])
    # 10 µm inside the wall, radially: r_mean (|q| / r(theta) - 1) = -10 µm · r_mean / r(theta),
    # within ±2.5 % of -10 µm at 5 % ovality (exact up to second order in the 10 µm).
    np.testing.assert_allclose(oval_residuals(x, inside), -0.01 * 32.5 / r_theta, rtol=1e-3)


@settings(max_examples=30, deadline=None)
@given(a=st.floats(-0.1, 0.1), b=st.floats(-0.1, 0.1), dx=st.floats(-5, 5),
       dy=st.floats(-5, 5), r=st.floats(20, 40), c=st.floats(-0.1, 0.1),
       s=st.floats(-0.1, 0.1))
def test_jacobian_is_the_residuals_derivative(a, b, dx, dy, r, c, s) -> None:
    """The closed-form derivatives against central differences of the residuals."""
    pose = Pose.from_degrees(3.0, -2.0, 1.5, -0.5)
    points = laser_ring(pose, PipeSection.oval(65.0, 0.03, 0.4), D, n_points=90)
    x = np.array([a, b, dx, dy, r, c, s])
    steps = np.array([1e-7, 1e-7, 1e-6, 1e-6, 1e-6, 1e-7, 1e-7])
    numeric = np.column_stack([
        (oval_residuals(x + h * e, points) - oval_residuals(x - h * e, points)) / (2 * h)
        for h, e in zip(steps, np.eye(7), strict=True)])
    np.testing.assert_allclose(oval_jacobian(x, points), numeric, rtol=1e-6,
                               atol=1e-6 * np.abs(numeric).max())
    # the fit with its tilt held takes the other five columns, computed alone
    np.testing.assert_array_equal(oval_jacobian(x, points, tilt=False),
                                  oval_jacobian(x, points)[:, 2:])


def test_one_ring_cannot_separate_tilt_from_ovality() -> None:
    """The same ring fits a wrong tilt with another ovality almost as well: the reason
    the tilt has to come from elsewhere (the LED frames) before ovality is measured."""
    pose = Pose.from_degrees(4.0, 0.0, 1.0, -1.0)
    ring = laser_ring(pose, PipeSection.oval(65.0, 0.03, 0.0), D, n_points=360)
    right = fit_section(ring, pose, 32.5)
    wrong = fit_section(ring, Pose(0.0, 0.0, 1.0, -1.0), 32.5)
    assert right.section.ovality == pytest.approx(0.03, abs=1e-7)
    # Tilting by tau stretches the ring by 1/cos(tau): 4° reads as ~0.24 % more or less
    # ovality, while the residual stays far below a realistic point noise (0.05 mm).
    assert abs(wrong.section.ovality - 0.03) > 0.001
    assert wrong.rms_mm < 0.02
    # The fit's own information says so: two pose directions are (nearly) unseen.
    assert np.sum(np.linalg.eigvalsh(wrong.information) > 1e-3 * np.abs(
        wrong.information).max()) == 2


def test_the_section_free_prior_leaves_the_tilt_to_other_evidence() -> None:
    """At a circle fit of a ring, the information on the pose with the section left free
    is what fit_section reports there: two directions of the pose (a tilt with the offset
    that keeps the ring in place, which an ovality mimics) are nearly unseen."""
    pose = Pose.from_degrees(3.0, -1.0, 1.0, -1.0)
    rng = np.random.default_rng(0)
    ring = laser_ring(pose, PipeSection.circle(65.0), D, n_points=360)
    ring = ring + np.column_stack([rng.normal(0, 0.02, (360, 2)), np.zeros(360)])
    free = section_free_information(ring, pose, 32.5)
    fitted = fit_section(ring, pose, 32.5)
    np.testing.assert_allclose(free, fitted.information, rtol=0.05,
                               atol=1e-4 * np.abs(fitted.information).max())
    # two pose directions (tilt with the offset that keeps the ring) nearly unseen
    eigen = np.linalg.eigvalsh(free)
    assert np.sum(eigen > 1e-3 * eigen.max()) == 2
