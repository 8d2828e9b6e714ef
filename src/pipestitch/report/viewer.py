"""Static pan-and-zoom viewer of the full-resolution mosaic, from its Deep Zoom tiles.

:func:`render_viewer` makes ``viewer.html``: OpenSeadragon (BSD-3-Clause, vendored
unchanged in ``report/static/openseadragon``, inlined into the page) showing the tile
folder written by :func:`pipestitch.io.tiles.write_pyramid`. It works from ``file://``
with no server: the Deep Zoom description is inlined (no XML request, which browsers
refuse from file://), tiles are loaded as plain images by relative URL, and the
canvas drawer is used because file:// images are cross-origin for WebGL. The pointer's
wall position (z in mm, theta in degrees, as in mosaic.json) is shown under the view.

It does not copy the tiles: the page refers to them relative to its own folder, so
keep the two together.
"""

from __future__ import annotations

import html
import json
from importlib import resources

__all__ = ["VIEWER_NAME", "openseadragon_js", "render_viewer"]

VIEWER_NAME = "viewer.html"


def openseadragon_js() -> str:
    """OpenSeadragon's script (vendored, BSD-3-Clause), to inline into a page."""
    path = resources.files("pipestitch.report") / "static" / "openseadragon"
    return (path / "openseadragon.min.js").read_text(encoding="utf-8")


def render_viewer(source: dict[str, object], *, title: str = "pipestitch mosaic",
                  z0_mm: float = 0.0, mm_per_px: float | None = None,
                  deg_per_px: float | None = None) -> str:
    """The text of ``viewer.html`` showing the Deep Zoom tile source ``source``.

    Parameters
    ----------
    source : dict
        OpenSeadragon's inline tile source (:func:`pipestitch.io.tiles.read_dzi`) with
        ``source["Image"]["Url"]`` set to the tile folder relative to the page.
    title : str
        Page title.
    z0_mm, mm_per_px, deg_per_px : float, optional
        The mosaic's axes (mosaic.json): when given, the pointer's z and theta are shown.

    Returns
    -------
    str
        The page (HTML).
    """
    axes = ({"z0_mm": z0_mm, "mm_per_px": mm_per_px, "deg_per_px": deg_per_px}
            if mm_per_px is not None and deg_per_px is not None else None)
    return _PAGE.format(title=html.escape(title), osd=openseadragon_js(),
                        source=json.dumps(source), axes=json.dumps(axes))


# Hand-written page around the library: a full-window view, zoom buttons (the stock
# navigation buttons need image files), the navigator overview and the pointer's
# position on the wall.
_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>{title}</title>
<style>
html, body {{ margin: 0; height: 100%; background: #111; color: #ddd;
  font: 14px system-ui, sans-serif; }}
#bar {{ position: fixed; top: 0; left: 0; right: 0; height: 32px; padding: 4px 8px;
  box-sizing: border-box; display: flex; gap: 8px; align-items: center; background: #222; }}
#bar button {{ min-width: 28px; }}
#view {{ position: fixed; top: 32px; bottom: 0; left: 0; right: 0; }}
</style></head>
<body>
<div id="bar"><strong>{title}</strong>
<button id="zoom-in" title="Zoom in">+</button>
<button id="zoom-out" title="Zoom out">&minus;</button>
<button id="home" title="Whole mosaic">&#8962;</button>
<span id="where">drag to pan, wheel to zoom</span></div>
<div id="view"></div>
<script>{osd}</script>
<script>
"use strict";
const axes = {axes};
const viewer = OpenSeadragon({{
  id: "view", tileSources: {source}, drawer: "canvas", showNavigationControl: false,
  showNavigator: true, navigatorPosition: "BOTTOM_RIGHT", maxZoomPixelRatio: 8,
  visibilityRatio: 0.5, constrainDuringPan: true, crossOriginPolicy: false,
  imageSmoothingEnabled: false
}});
document.getElementById("zoom-in").onclick = () => viewer.viewport.zoomBy(2);
document.getElementById("zoom-out").onclick = () => viewer.viewport.zoomBy(0.5);
document.getElementById("home").onclick = () => viewer.viewport.goHome();
new OpenSeadragon.MouseTracker({{ element: viewer.container, moveHandler: (event) => {{
  const item = viewer.world.getItemAt(0);
  if (!item) return;
  const point = item.viewerElementToImageCoordinates(event.position);
  // OpenSeadragon's pixel i spans [i, i + 1); SPEC's pixel i is centred on i.
  const col = Math.floor(point.x), row = Math.floor(point.y);
  let text = "col " + col + ", row " + row;
  if (axes) {{
    const z = axes.z0_mm + col * axes.mm_per_px;
    const theta = ((row * axes.deg_per_px) % 360 + 360) % 360;
    text = "z " + z.toFixed(1) + " mm, \\u03b8 " + theta.toFixed(1) + "\\u00b0 (" + text + ")";
  }}
  document.getElementById("where").textContent = text;
}} }});
window.pipestitchViewer = viewer;
</script>
</body></html>
"""
