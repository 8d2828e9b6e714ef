"""Shared fixtures of the mosaic stage's tests: textures, shifts and a rendered wall."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import pytest

from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, WallGrid
from pipestitch.simulate.render import Optics, Renderer, WallTexture
from pipestitch.simulate.textures import Defect, make_wall

R = 32.5


def random_texture(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (0.5 + cv2.GaussianBlur(rng.random(shape), (0, 0), 1.5)).astype(np.float32)


def shifted_image(img: np.ndarray, d_rows: float, d_cols: float) -> np.ndarray:
    """img(x + d), rows wrapping (as the pipe does)."""
    rows, cols = np.mgrid[0:img.shape[0], 0:img.shape[1]].astype(np.float32)
    return cv2.remap(img, cols + d_cols, rows + d_rows, cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_WRAP)


@pytest.fixture(scope="session")
def texture() -> Callable[..., np.ndarray]:
    """``texture(shape, seed=0)``: a smooth random texture around 0.5 (float32)."""
    return random_texture


@pytest.fixture(scope="session")
def shifted() -> Callable[..., np.ndarray]:
    """``shifted(img, d_rows, d_cols)``: ``img(x + d)``, rows wrapping."""
    return shifted_image


@pytest.fixture(scope="module")
def holed_renderer() -> Renderer:
    """A corroded 65 mm wall with one 6 mm hole at z = 60 mm, theta = 200 deg."""
    grid = WallGrid.square(R, 0.07, -40.0, 200.0)
    albedo = make_wall("corrosion", grid, rng=np.random.default_rng(0),
                       defects=[Defect("hole", 60.0, 200.0, 6.0)])
    wall = WallTexture(albedo=albedo, grid=grid)
    return Renderer(default_camera("half"), PipeSection.circle(2 * R), wall, 16.0,
                    Optics(full_well_e=1e9))
