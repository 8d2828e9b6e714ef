"""The review page: the full-resolution mosaic with axes, defects, observations, a ruler,
the source frames and the profile and pose tracks, as one HTML text.

:func:`render_review` wraps OpenSeadragon (vendored in ``report/static/openseadragon``)
and the page's own script and style (``report/static/review.js``, ``review.css``), all
inlined, around the run's data (:class:`ReviewData`, as JSON). The page works from
``file://`` read-only (as ``viewer.html``: inline tile source, canvas drawer, tiles by
relative URL); served by ``pipestitch review`` it also edits observations and shows the
source frames, through the server's ``api/`` URLs.

Coordinates: the mosaic's column ``j`` is at z = z0_mm + j * mm_per_px and row ``i`` at
theta = i * deg_per_px, pixel centres at integers (SPEC); OpenSeadragon's pixel ``j``
spans [j, j + 1), so the page places wall point (z, theta) at image coordinates
(j + 0.5, i + 0.5). Distances on the wall take mm_per_px along the pipe and
mm_per_px_circumferential (2 pi r / n_rows) around it.
"""

from __future__ import annotations

import html
import json
from dataclasses import asdict, dataclass, field
from importlib import resources

from pipestitch.report.viewer import openseadragon_js

__all__ = ["REVIEW_NAME", "ReviewData", "ReviewGrid", "render_review"]

REVIEW_NAME = "review.html"


@dataclass(frozen=True)
class ReviewGrid:
    """The full-resolution mosaic's scale (mosaic.json ``full_resolution``)."""

    z0_mm: float
    mm_per_px: float                  # along the pipe
    deg_per_px: float
    n_rows: int
    n_cols: int
    mm_per_px_circumferential: float  # around the pipe, at the run's radius


@dataclass
class ReviewData:
    """Everything the page shows, in plain JSON-able values.

    ``defects`` and ``observations`` are lists of dicts with the columns of defects.csv
    and observations.csv (observations also carry ``index``, their row in the file);
    ``poses`` and ``profile`` hold one list per column (``frame``, ``z_mm``, ...);
    ``nodata`` is a PNG data URI of the no-data mask at the overview's scale, or None.
    """

    title: str
    tiles: dict[str, object]          # OpenSeadragon inline tile source, Url relative
    grid: ReviewGrid
    crown_theta_deg: float
    reference: str
    start_z_mm: float
    window_mm: tuple[float, float]
    nominal_diameter_mm: float
    defects: list[dict[str, object]] = field(default_factory=list)
    observations: list[dict[str, object]] = field(default_factory=list)
    version: str = ""                 # observations.csv's digest: an edit names the one it read
    poses: dict[str, list[float]] = field(default_factory=dict)
    profile: dict[str, list[float]] = field(default_factory=dict)
    nodata: str | None = None
    editable: bool = False            # served by `pipestitch review` (else read-only)
    frames_url: str | None = None     # where the server gives source frames, if it can
    codes: dict[str, str] = field(default_factory=dict)   # main codes offered in the form


def _static(name: str) -> str:
    return (resources.files("pipestitch.report") / "static" / name).read_text(encoding="utf-8")


def _json_for_script(data: object) -> str:
    """JSON safe inside a <script> element (no "</script>", no HTML comment opener)."""
    text = json.dumps(data, allow_nan=False, separators=(",", ":"))
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_review(data: ReviewData) -> str:
    """The text of the review page for ``data``.

    Parameters
    ----------
    data : ReviewData
        The run's mosaic, findings and tracks (NaN must already be None).

    Returns
    -------
    str
        The page (HTML), with no external resource but the tiles it names.
    """
    return _PAGE.format(title=html.escape(data.title), osd=openseadragon_js(),
                        style=_static("review.css"), script=_static("review.js"),
                        data=_json_for_script(asdict(data)))


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>{title}</title>
<style>{style}</style></head>
<body>
<header id="bar"><strong>{title}</strong>
<span class="group"><button id="zoom-in" title="Zoom in">+</button>
<button id="zoom-out" title="Zoom out">&minus;</button>
<button id="home" title="Whole mosaic">&#8962;</button>
<button id="full" title="Full resolution: one screen pixel per mosaic pixel">1:1</button></span>
<span class="group" id="tools">tool:
<label><input type="radio" name="tool" value="frames" checked> source frames</label>
<label><input type="radio" name="tool" value="ruler"> ruler</label>
<label><input type="radio" name="tool" value="area"> area</label>
<label><input type="checkbox" id="show-nodata" checked> no data</label></span>
<span id="where">drag to pan, wheel to zoom</span>
<span id="mode"></span></header>
<main>
<section id="left">
<div id="view-wrap"><div id="view"></div><canvas id="axes"></canvas>
<div id="ruler-readout" class="readout"></div></div>
<canvas id="tracks" height="210"></canvas>
</section>
<aside id="side">
<h2>Defects</h2><div id="defect-list"></div>
<h2>Observations</h2><div id="obs-note" class="note"></div>
<div id="obs-list"></div>
<form id="obs-form" hidden><h3 id="obs-form-title">Observation</h3>
<div class="grid">
<label>distance (m)<input name="distance_m" required></label>
<label>code<input name="code" list="codes" required></label>
<label>char. 1<input name="char1" maxlength="1"></label>
<label>char. 2<input name="char2" maxlength="1"></label>
<label>quant. 1<input name="quant1"></label>
<label>quant. 2<input name="quant2"></label>
<label>clock from<input name="clock_from"></label>
<label>clock to<input name="clock_to"></label>
<label>continuous<input name="continuous"></label>
<label>reference<input name="ref"></label></div>
<label>remark<textarea name="remark" rows="2"></textarea></label>
<datalist id="codes"></datalist>
<div><button type="submit" id="obs-save">Save</button>
<button type="button" id="obs-cancel">Cancel</button>
<span id="obs-error" class="error"></span></div></form>
<button id="obs-add" hidden>Add an observation at the last point clicked</button>
<h2>Source frames</h2><div id="frames" class="note">Click the wall (tool: source frames)
to list the frames that saw that point.</div>
</aside></main>
<script>{osd}</script>
<script id="review-data" type="application/json">{data}</script>
<script>{script}</script>
</body></html>
"""
