"""A wall by texture name, with its defects drawn on it (:func:`make_wall`)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from pipestitch.geometry import WallGrid
from pipestitch.simulate.textures.aluminium import aluminium_texture
from pipestitch.simulate.textures.chart import chart_texture
from pipestitch.simulate.textures.corrosion import corrosion_texture
from pipestitch.simulate.textures.photo import photo_texture
from pipestitch.simulate.textures.wall_defects import Defect, _draw_defects_inplace

__all__ = ["TEXTURE_KINDS", "make_wall"]

TEXTURE_KINDS = ("chart", "corrosion", "aluminium", "photo")


def make_wall(kind: str, grid: WallGrid, *, rng: np.random.Generator | int,
              defects: Iterable[Defect] = (), photo: np.ndarray | None = None,
              photo_tile_mm: float = 30.0) -> np.ndarray:
    """Wall albedo of a given texture, with defects drawn on it.

    Parameters
    ----------
    kind : {"chart", "corrosion", "aluminium", "photo"}
        Texture (see the corresponding ``*_texture`` function).
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source (unused for ``"photo"``).
    defects : iterable of Defect
        Drawn after the texture (see :func:`draw_defects`).
    photo : numpy.ndarray, optional
        Grey photo, required for ``kind="photo"``.
    photo_tile_mm : float
        Width of one copy of the photo along z (mm), for ``kind="photo"``.

    Returns
    -------
    numpy.ndarray, shape grid.shape, float32
        Albedo in [0, 1].
    """
    if kind == "chart":
        out = chart_texture(grid, rng)
    elif kind == "corrosion":
        out = corrosion_texture(grid, rng)
    elif kind == "aluminium":
        out = aluminium_texture(grid, rng)
    elif kind == "photo":
        if photo is None:
            raise ValueError('make_wall: kind="photo" needs a photo image')
        out = photo_texture(grid, photo, photo_tile_mm)
    else:
        raise ValueError(f"make_wall: unknown texture {kind!r}; expected one of {TEXTURE_KINDS}")
    _draw_defects_inplace(out, grid, defects)
    return out
