"""The (theta, z) wall grid: coordinates, validation, and its two square-pixel
constructors (the simulator's wall images, the mosaic's windows)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipestitch.geometry import WallGrid

R = 32.5


def _is_5_smooth(n: int) -> bool:
    for p in (2, 3, 5):
        while n % p == 0:
            n //= p
    return n == 1


def test_grid_rows_and_coordinates() -> None:
    g = WallGrid(radius_mm=20.0, mm_per_px_axial=0.1, deg_per_px=0.25, z0_mm=-3.0, n_cols=50)
    assert g.n_rows == 1440
    assert g.shape == (1440, 50)
    theta, z = g.theta_z()
    assert theta.shape == (1440,) and z.shape == (50,)
    assert theta[0] == 0.0 and theta[-1] == pytest.approx(360.0 - 0.25)
    assert np.allclose(np.diff(theta), 0.25)
    assert z[0] == -3.0 and z[-1] == pytest.approx(-3.0 + 49 * 0.1)
    assert g.mm_per_px_circ == pytest.approx(20.0 * math.radians(0.25))
    assert g.circumference_mm == pytest.approx(2 * math.pi * 20.0)
    assert g.length_mm == pytest.approx(5.0)
    assert g.to_json() == {"mm_per_px_axial": 0.1, "deg_per_px": 0.25, "z0_mm": -3.0,
                           "radius_mm": 20.0}


def test_theta0_turns_the_rows() -> None:
    g = WallGrid(radius_mm=20.0, deg_per_px=0.5, mm_per_px_axial=0.1, z0_mm=0.0, n_cols=5,
                 theta0_deg=-12.5)
    theta, _ = g.theta_z()
    assert theta[0] == -12.5 and theta[1] == pytest.approx(-12.0)
    # SPEC wall images start at theta 0: their metadata cannot say otherwise.
    with pytest.raises(ValueError, match="theta 0"):
        g.to_json()


@pytest.mark.parametrize("bad", [
    {"deg_per_px": 0.7},                 # 360 / 0.7 is not an integer
    {"deg_per_px": 0.0},
    {"deg_per_px": 1e9},                 # less than one row around the pipe
    {"radius_mm": -1.0},
    {"mm_per_px_axial": 0.0},
    {"n_cols": 0},
    {"n_cols": 2.5},
    {"z0_mm": float("nan")},
    {"theta0_deg": float("inf")},
])
def test_grid_rejects_bad_values(bad: dict) -> None:
    args = {"radius_mm": 10.0, "mm_per_px_axial": 0.1, "deg_per_px": 0.5, "z0_mm": 0.0,
            "n_cols": 10} | bad
    with pytest.raises(ValueError, match=f"WallGrid.{next(iter(bad))}"):
        WallGrid(**args)


def test_fields_are_keyword_only() -> None:
    with pytest.raises(TypeError):
        WallGrid(10.0, 0.5, 0.1, 0.0, 10)  # type: ignore[misc]


def test_grid_accepts_float_roundoff() -> None:
    n = 5105
    g = WallGrid(radius_mm=32.5, deg_per_px=360.0 / n, mm_per_px_axial=0.04, z0_mm=0.0, n_cols=3)
    assert g.n_rows == n


@pytest.mark.parametrize(("radius", "pitch"), [(32.5, 0.04), (41.5, 0.07), (5.0, 0.1), (25.0, 0.3)])
def test_square_grid_pitch(radius: float, pitch: float) -> None:
    g = WallGrid.square(radius, pitch, 10.0, 70.0)
    n = 360.0 / g.deg_per_px
    assert abs(n - round(n)) < 1e-9
    # Rounding the row count moves the arc pitch by at most half a row per turn.
    assert abs(g.mm_per_px_circ - pitch) <= 0.5 * pitch / g.n_rows + 1e-12
    assert g.mm_per_px_axial == pitch
    _, z = g.theta_z()
    assert z[0] == 10.0 and abs(z[-1] - 70.0) <= 0.5 * pitch
    with pytest.raises(ValueError):
        WallGrid.square(radius, pitch, 5.0, 5.0)


def test_window_grid() -> None:
    g = WallGrid.window(R, 0.5, 20.0, 60.0)
    # 80 columns from z0 (the window's far end is not a column centre, unlike square's).
    assert g.n_cols == 80 and g.z0_mm == 20.0 and g.theta0_deg == 0.0
    assert abs(g.n_rows * 0.5 - 2 * np.pi * R) < 0.5
    assert g.mm_per_px_axial == 0.5 and g.radius_mm == R
    with pytest.raises(ValueError, match="integer"):
        WallGrid(radius_mm=R, deg_per_px=0.7, mm_per_px_axial=0.5, z0_mm=0.0, n_cols=10)


@pytest.mark.parametrize(("pitch", "window"), [(0.135, (5.0, 70.0)), (0.27, (-3.0, 41.0)),
                                               (0.05, (10.0, 90.0))])
def test_window_fft_sizes(pitch: float, window: tuple[float, float]) -> None:
    plain = WallGrid.window(R, pitch, *window)
    fast = WallGrid.window(R, pitch, *window, fft_sizes=True)
    # Each size is rounded up to the next product of 2, 3 and 5, counted here by brute force.
    assert fast.n_rows == next(k for k in range(plain.n_rows, 2 * plain.n_rows) if _is_5_smooth(k))
    assert fast.n_cols == next(k for k in range(plain.n_cols, 2 * plain.n_cols) if _is_5_smooth(k))
    assert fast.z0_mm == plain.z0_mm and fast.mm_per_px_axial == plain.mm_per_px_axial
