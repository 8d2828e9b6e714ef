"""Synthetic unrolled pipe-wall textures (albedo images) for the probe simulator.

An unrolled wall image holds the wall's albedo on a
:class:`pipestitch.geometry.WallGrid` (rows around the pipe from theta 0, columns
along it; conventions in ``geometry/wall_grid.py``). Every texture here is seamless
across the wrap from the last row to row 0.

What it offers (this package re-exports them; one module per kind)

* Four wall textures, all ``float32`` in ``[0, 1]``:
  :func:`chart_texture` (``chart.py``: high-contrast test chart, defined in
  millimetres so it looks the same at any resolution), :func:`corrosion_texture`
  (``corrosion.py``: 1/f noise, stains, pits), :func:`aluminium_texture`
  (``aluminium.py``: bright, feature-poor, axially brushed) and
  :func:`photo_texture` (``photo.py``: mirror-tiled grey photo).
* :class:`Defect`, :func:`draw_defects` (holes and stains drawn as true circles in
  millimetres on the cylinder, antialiased analytically) and
  :func:`reference_test_piece` (the 7-hole reference cross), in ``wall_defects.py``.
* :func:`make_wall` (``walls.py``) - texture by name, then defects.

``_texture_common.py`` holds what several textures share (the random source, the
antialiasing ramp, the periodic noise lattice and its wrapped resampling).

What it does not do: no file I/O, no rendering through a camera, no colour, no
surface relief (holes and pits only change the albedo, not the wall geometry).

Everything is vectorised; a 65 mm pipe at 0.04 mm/px (~5100 x 6000 px) takes well
under 2 s per texture on 2 cores. Every function is deterministic for a given
:class:`numpy.random.Generator` state.

May import ``camera`` (the grey conversion of a photo) and ``geometry``; must not
import ``pose``, ``io``, ``pipeline`` or ``cli`` (nor the rest of ``simulate``: the
renderer and the scenarios build on the textures, not the other way round).
"""

from __future__ import annotations

from pipestitch.simulate.textures.aluminium import aluminium_texture
from pipestitch.simulate.textures.chart import chart_texture
from pipestitch.simulate.textures.corrosion import corrosion_texture
from pipestitch.simulate.textures.photo import photo_texture
from pipestitch.simulate.textures.wall_defects import (
    DEFECT_KINDS,
    HOLE_ALBEDO,
    SPOT_FACTOR,
    SPOT_SOFT_FRACTION,
    Defect,
    draw_defects,
    reference_test_piece,
)
from pipestitch.simulate.textures.walls import TEXTURE_KINDS, make_wall

__all__ = [
    "DEFECT_KINDS",
    "HOLE_ALBEDO",
    "SPOT_FACTOR",
    "SPOT_SOFT_FRACTION",
    "TEXTURE_KINDS",
    "Defect",
    "aluminium_texture",
    "chart_texture",
    "corrosion_texture",
    "draw_defects",
    "make_wall",
    "photo_texture",
    "reference_test_piece",
]
