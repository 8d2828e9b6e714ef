"""The inspection report: one self-contained HTML file, plots embedded as PNG data URIs.

Pure: takes the run's results as plain data and returns the HTML text; the pipeline
writes it. Plots are drawn with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import base64
import functools
import html
import io
import math
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING

import cv2
import numpy as np

from pipestitch.measure.defects import Defect
from pipestitch.standards import DEFINITIONS, Observation, Survey
from pipestitch.standards.observations import ProfileSection

if TYPE_CHECKING:
    import matplotlib.pyplot as plt
    from matplotlib.transforms import Bbox

__all__ = ["FrameRow", "ReportData", "StandardsView", "agg_pyplot", "observation_section",
           "render_report", "with_observation_section"]

MAX_MOSAIC_PX = 1400     # the embedded mosaic is downscaled to at most this many pixels
MAX_FIGURE_HEIGHT_IN = 40.0   # the mosaic figure's height at most (4400 px; its width is <= 16 in)
OVALITY_FLAG_PCT = 1.0   # sections listed from this ASTM F1216 ovality (%)
MAX_LISTED = 200         # rows of a list (exceedances, problems) shown; the rest in its CSV
BIN_M = 1.0              # the summary's section length along the pipe
PROBLEMS_CSV = "problems.csv"
# The coded observations lie between these (user text is escaped: "<!--" never occurs in
# it), so an edit in the review page re-renders only them (with_observation_section).
OBSERVATIONS_BEGIN, OBSERVATIONS_END = "<!-- observations -->", "<!-- /observations -->"
TABLES = (("poses.csv", "pose of every frame (both mirror hypotheses)"),
          ("profile.csv", "diameter and ovality of every ring"),
          ("ovality.csv", "named ovality figures of every section"),
          ("defects.csv", "every defect"), ("observations.csv", "the coded observations"),
          (PROBLEMS_CSV, "every frame that failed, was skipped or stayed ambiguous"))


@dataclass(frozen=True)
class FrameRow:
    """One frame's line in the report (angles in degrees, lengths in mm; NaN = none)."""

    frame: int
    z_mm: float
    alpha_deg: float
    beta_deg: float
    dx_mm: float
    dy_mm: float
    diameter_mm: float
    ambiguous: bool
    chosen_by: str
    # one-sigma of alpha, beta (deg), dx, dy (mm) as poses.csv states them
    sigma: tuple[float, float, float, float] = (math.nan,) * 4


@dataclass(frozen=True)
class StandardsView:
    """The standards stage's results as the report shows them."""

    reference_source: str            # "imu", "invert-detected", "user (--crown-deg)", "relative"
    reference_detail: str
    crown_theta_deg: float           # mosaic theta of 12 o'clock
    observations: list[Observation] = field(default_factory=list)
    sections: list[ProfileSection] = field(default_factory=list)
    survey: Survey | None = None     # the survey header the exchange files carry


@dataclass
class ReportData:
    """Everything the report shows."""

    title: str
    mosaic: np.ndarray | None           # uint8, 0 = no data; None: no mosaic
    z0_mm: float
    mm_per_px: float
    deg_per_px: float
    nominal_diameter_mm: float
    frames: list[FrameRow]
    problems: list[tuple[int, str]] = field(default_factory=list)
    figures: dict[str, str] = field(default_factory=dict)
    defects: list[Defect] = field(default_factory=list)
    tolerance_pct: float = 1.0
    standards: StandardsView | None = None
    viewer_href: str | None = None      # relative link to the pan-and-zoom viewer page
    review_href: str | None = None      # relative link to the review page
    tables: list[str] = field(default_factory=list)   # CSV files beside the report to link
    # figures already drawn (:func:`draw_track_figures`); the others are drawn on render
    drawn: dict[str, str] = field(default_factory=dict)


@functools.cache
def agg_pyplot() -> ModuleType:
    """matplotlib's pyplot on the Agg backend (no display), imported on first use: a
    quarter of a second that commands without plots (and the report's callers until it is
    drawn) do not pay. Every plot of the package is drawn through it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot

    return matplotlib.pyplot


FIGURE_DPI = 110


def _png(fig: plt.Figure) -> str:
    """The plot as a PNG data URI, cropped to its tight box (it holds no image)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=FIGURE_DPI, bbox_inches="tight")
    agg_pyplot().close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _mosaic_figure(data: ReportData) -> str:
    plt = agg_pyplot()
    img = data.mosaic
    scale = min(1.0, MAX_MOSAIC_PX / max(img.shape))
    shown = img if scale == 1.0 else cv2.resize(img, None, fx=scale, fy=scale,
                                                interpolation=cv2.INTER_AREA)
    theta_max = img.shape[0] * data.deg_per_px
    tall = shown.shape[0] / shown.shape[1]
    # the image's own aspect; narrower only where that would pass the height limit (a
    # mosaic tens of times taller than wide), squeezed only when even 3 inches would
    width = min(16.0, 3 + shown.shape[1] / 120, max(3.0, (MAX_FIGURE_HEIGHT_IN - 0.8) / tall))
    fig, ax = plt.subplots(figsize=(width, min(MAX_FIGURE_HEIGHT_IN, width * tall + 0.8)))
    ax.set_xlim(data.z0_mm, data.z0_mm + img.shape[1] * data.mm_per_px)
    ax.set_ylim(theta_max, 0)
    ax.set_xlabel("z along the pipe (mm)")
    ax.set_ylabel("θ around the pipe (deg, relative)")
    ax.set_yticks(np.arange(0, 361, 45))
    _outline_defects(ax, data)
    if data.standards is not None:
        _clock_axis(ax, data.standards.crown_theta_deg, theta_max)
    return _jpeg_under(fig, ax, _with_unseen(shown))


UNSEEN_RGB = (0x40, 0x20, 0x20)   # the mosaic's pixels no frame saw (value 0): dark red


def _with_unseen(grey: np.ndarray) -> np.ndarray:
    """An 8-bit grey mosaic as RGB, its unseen pixels (0) dark red."""
    rgb = np.repeat(grey[..., None], 3, axis=2)
    rgb[grey == 0] = UNSEEN_RGB
    return rgb


def _jpeg_under(fig: plt.Figure, ax: plt.Axes, rgb: np.ndarray) -> str:
    """The figure drawn over ``rgb`` (8-bit RGB) filling ``ax``, cropped as
    ``bbox_inches="tight"``, as a JPEG data URI (quality 90: a tenth of a PNG's bytes).

    The image is scaled to the axes' pixels (area-averaged when shrunk, nearest when
    enlarged) and the figure's transparent rendering laid over it, rather than drawn by
    ``imshow``: the same picture, but matplotlib resamples an image through float RGBA
    buffers (~100 MB for the report's mosaic: 0.3-1.1 s, most of it first touches of new
    memory, the run's last serial step) and this takes a third of that memory and
    0.1 s.
    """
    fig.patch.set_alpha(0.0)
    for a in fig.axes:
        a.patch.set_alpha(0.0)
    fig.set_dpi(FIGURE_DPI)
    fig.canvas.draw()
    over = np.asarray(fig.canvas.buffer_rgba())
    height = over.shape[0]
    box = ax.get_window_extent()   # display pixels, origin bottom left
    x0, x1 = round(box.x0), round(box.x1)
    r0, r1 = height - round(box.y1), height - round(box.y0)
    base = np.full(over.shape[:2] + (3,), 255, np.uint8)
    shrink = x1 - x0 < rgb.shape[1] or r1 - r0 < rgb.shape[0]
    base[r0:r1, x0:x1] = cv2.resize(rgb, (x1 - x0, r1 - r0),
                                    interpolation=cv2.INTER_AREA if shrink else cv2.INTER_NEAREST)
    alpha = over[..., 3:].astype(np.float32) / 255.0
    picture = (over[..., :3] * alpha + base * (1.0 - alpha) + 0.5).astype(np.uint8)
    pad = agg_pyplot().rcParams["savefig.pad_inches"]
    tight = fig.get_tightbbox(fig.canvas.get_renderer()).padded(pad)   # inches
    agg_pyplot().close(fig)
    picture = _crop(picture, tight, height)
    ok, jpeg = cv2.imencode(".jpg", picture[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise ValueError(f"report: the mosaic figure of {picture.shape[1]} x "
                         f"{picture.shape[0]} pixels could not be encoded as JPEG")
    return "data:image/jpeg;base64," + base64.b64encode(jpeg.tobytes()).decode("ascii")


def _crop(picture: np.ndarray, box: Bbox, height: int) -> np.ndarray:
    """The part of ``picture`` (rendered at FIGURE_DPI, ``height`` rows) in ``box``
    (inches from the bottom left), sized as ``savefig`` sizes it; white past its edges."""
    c0, r1 = round(box.x0 * FIGURE_DPI), height - round(box.y0 * FIGURE_DPI)
    c1, r0 = c0 + int(box.width * FIGURE_DPI), r1 - int(box.height * FIGURE_DPI)
    h, w = picture.shape[:2]
    padded = np.pad(picture, ((max(0, -r0), max(0, r1 - h)), (max(0, -c0), max(0, c1 - w)),
                              (0, 0)), constant_values=255)
    dr, dc = max(0, -r0), max(0, -c0)   # rows and columns the padding added before
    return padded[r0 + dr:r1 + dr, c0 + dc:c1 + dc]


def _clock_axis(ax: plt.Axes, crown_theta_deg: float, theta_max: float) -> None:
    """Clock positions on a right-hand axis; 12, 3, 6 and 9 o'clock as dotted lines."""
    right = ax.twinx()
    right.set_ylim(ax.get_ylim())
    ticks = [((crown_theta_deg + 30 * h) % 360, h or 12) for h in range(12)]
    ticks = sorted(t for t in ticks if t[0] <= theta_max)
    right.set_yticks([t for t, _ in ticks], [f"{h}" for _, h in ticks])
    right.set_ylabel("clock position (12 = crown)")
    for theta, hour in ticks:
        if hour in (12, 3, 6, 9):
            ax.axhline(theta, color="#30a0ff", lw=0.8, ls=":", alpha=0.8)


def _outline_defects(ax: plt.Axes, data: ReportData) -> None:
    """Each defect as an ellipse of its equivalent diameter (in mm and degrees), labelled."""
    from matplotlib.patches import Ellipse

    deg_per_mm = 360.0 / (data.mosaic.shape[0] * data.mm_per_px) if data.mosaic is not None else 1
    for k, d in enumerate(data.defects, start=1):
        colour = "#ff3030" if d.kind == "hole" else "#ffb000"
        ax.add_patch(Ellipse((d.z_mm, d.theta_deg), 1.6 * d.diameter_mm,
                             1.6 * d.diameter_mm * deg_per_mm, fill=False, color=colour, lw=1.2))
        ax.annotate(f"D{k} {d.clock}", (d.z_mm + d.diameter_mm, d.theta_deg), color=colour,
                    fontsize=8, weight="bold")


def _series(data: ReportData, name: str) -> np.ndarray:
    return np.array([getattr(f, name) for f in data.frames], dtype=float)


def _pose_figure(data: ReportData) -> str:
    plt = agg_pyplot()
    z = _series(data, "z_mm")
    fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    sigma = np.array([f.sigma for f in data.frames], dtype=float).reshape(-1, 4)
    order = np.argsort(z)
    for k, (name, label) in enumerate((("alpha_deg", "α"), ("beta_deg", "β"),
                                       ("dx_mm", "Δx"), ("dy_mm", "Δy"))):
        ax, value = axes[k // 2], _series(data, name)
        line = ax.plot(z, value, ".-", label=label)[0]
        if np.isfinite(sigma[:, k]).any():   # the stated 2-sigma band
            ax.fill_between(z[order], (value - 2 * sigma[:, k])[order],
                            (value + 2 * sigma[:, k])[order], color=line.get_color(),
                            alpha=0.15, lw=0)
    amb = np.array([f.ambiguous for f in data.frames], bool)
    if amb.any():
        for ax in axes:
            ax.plot(z[amb], np.zeros(amb.sum()), "rx", label="ambiguous")
    axes[0].set_ylabel("tilt (deg; bands ±2σ)")
    axes[1].set_ylabel("offset (mm; bands ±2σ)")
    axes[1].set_xlabel("z of the camera (mm)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    return _png(fig)


def _profile_figure(data: ReportData) -> str:
    plt = agg_pyplot()
    fig, ax = plt.subplots(figsize=(9, 3))
    ax.plot(_series(data, "z_mm"), _series(data, "diameter_mm"), ".-", label="from the ring")
    ax.axhline(data.nominal_diameter_mm, color="k", ls="--", lw=1, label="nominal")
    tol = data.tolerance_pct / 100 * data.nominal_diameter_mm
    ax.axhspan(data.nominal_diameter_mm - tol, data.nominal_diameter_mm + tol, color="g",
               alpha=0.08, label=f"±{data.tolerance_pct:g} % tolerance")
    ax.set_xlabel("z of the camera (mm)")
    ax.set_ylabel("diameter (mm)")
    ax.ticklabel_format(axis="y", useOffset=False)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def draw_track_figures(data: ReportData) -> dict[str, str]:
    """The pose track and the diameter profile as data URIs, for ``data.drawn``.

    They need only the per-frame rows, the nominal diameter and the tolerance, so a
    caller can draw them in a thread while it writes the other outputs (one thread at a
    time draws with pyplot).
    """
    return {"pose": _pose_figure(data), "profile": _profile_figure(data)}


def _table(headers: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
                   for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_STYLE = """body{font-family:system-ui,sans-serif;margin:2em;max-width:1400px;color:#222}
h1{font-size:1.6em}h2{font-size:1.2em;margin-top:1.6em}img{max-width:100%}
table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #ccc;padding:2px 8px}
th{background:#f0f0f0}.note{color:#555;font-size:.9em}"""


def _mosaic_section(data: ReportData) -> str:
    if data.mosaic is None:
        return "<p>No mosaic: the dataset has no LED frames.</p>"
    viewer = ("" if data.viewer_href is None else
              f'\n<p>Full resolution, pan and zoom (the tiles beside this file): '
              f'<a href="{html.escape(data.viewer_href)}">open the viewer</a>.</p>\n'
              f'<iframe id="viewer" title="zoomable mosaic" src="{html.escape(data.viewer_href)}" '
              'style="width:100%;height:420px;border:1px solid #ccc"></iframe>')
    st = data.standards
    theta = ("θ is relative to the first frame's roll" if st is None or
             st.reference_source == "relative" else
             f"θ in the mosaic's frame; 12 o'clock (crown) at θ = {st.crown_theta_deg:.1f}° by "
             f"the {html.escape(st.reference_source)} reference")
    return (f'<p class="note">Centralised mosaic at {data.mm_per_px:g} mm/px; {theta}. '
            "Dark red: not seen.</p>\n"
            f'<img id="mosaic" alt="mosaic of the pipe wall" src="{_mosaic_figure(data)}">'
            + viewer)


def _defect_table(data: ReportData) -> str:
    if not data.defects:
        return "<p>No defects found.</p>"
    rows = [[f"D{k}", d.kind, f"{d.z_mm:.1f}", f"{d.theta_deg:.1f}", d.clock,
             f"{d.diameter_mm:.2f}", f"{d.area_mm2:.1f}", f"{d.confidence:.2f}",
             "yes" if d.partial else ""]
            for k, d in enumerate(data.defects[:MAX_LISTED], start=1)]
    return _listed(len(data.defects), "defects.csv") + _table(
        ["id", "kind", "z (mm)", "θ (deg)", "clock", "diameter (mm)", "area (mm²)",
         "confidence", "partial"], rows)


def _clock_text(o: Observation) -> str:
    if o.clock_from is None:
        return ""
    return f"{o.clock_from}" if o.clock_to is None else f"{o.clock_from}–{o.clock_to}"


def _q(value: int | None) -> str:
    return "" if value is None else str(value)


def _clock_note(data: ReportData) -> str:
    if data.standards is None:
        return "12 o'clock = the first frame's image up (θ = 270°)"
    return html.escape(f"12 o'clock = crown at mosaic θ = {data.standards.crown_theta_deg:.1f}° "
                       f"(reference: {data.standards.reference_source})")


def _observation_body(view: StandardsView | None) -> str:
    if view is None:
        return "<p>Not coded (the standards stage did not run).</p>"
    note = (f'<p class="note">Clock reference: <b>{html.escape(view.reference_source)}</b> '
            f"({html.escape(view.reference_detail)}); 12 = crown, 3 = right, 6 = invert, "
            "9 = left, clockwise looking along the survey. Distance from the first wall seen "
            "(the mosaic's left edge), m. Codes: EN 13508-2 main codes (docs/standards.md); "
            "edit them in <code>pipestitch review OUT</code> (which updates this list), or "
            "edit observations.csv and run <code>pipestitch export</code> to re-export.</p>")
    if not view.observations:
        return note + "<p>No observations.</p>"
    rows = [[f"{o.distance_m:.2f}", o.code, o.char1, o.char2, _q(o.quant1), _q(o.quant2),
             _clock_text(o), o.continuous, o.remark, o.ref]
            for o in view.observations[:MAX_LISTED]]
    headers = ["distance (m)", "code", "char. 1", "char. 2", "quant. 1", "quant. 2", "clock",
               "continuous", "remark", "reference"]
    return note + _listed(len(view.observations), "observations.csv") + _table(headers, rows)


def observation_section(view: StandardsView | None) -> str:
    """The report's coded observations (``view``: the standards stage's results, None when
    it did not run), between the markers :func:`with_observation_section` finds."""
    return f"{OBSERVATIONS_BEGIN}\n{_observation_body(view)}\n{OBSERVATIONS_END}"


def with_observation_section(report: str, view: StandardsView | None) -> str | None:
    """The report text ``report`` with its coded observations rendered again from
    ``view``; None when it has no such section (a report of an older version)."""
    begin = report.find(OBSERVATIONS_BEGIN)
    end = report.find(OBSERVATIONS_END, begin + 1)
    if begin < 0 or end < 0:
        return None
    return report[:begin] + observation_section(view) + report[end + len(OBSERVATIONS_END):]


_SURVEY_FIELDS = (("pipe_ref", "pipe"), ("start_node", "start node"),
                  ("finish_node", "finish node"), ("direction", "direction"),
                  ("material", "material"), ("shape", "shape"), ("date", "date"),
                  ("time", "time"), ("operator", "operator"), ("location", "location"),
                  ("reference_point", "longitudinal reference (EN ABC)"))


def _survey_section(data: ReportData) -> str:
    """The survey metadata (DATASET/survey.toml, else what the run knows)."""
    survey = data.standards.survey if data.standards is not None else None
    if survey is None:
        return ""
    rows = [[label, str(getattr(survey, name)) or "not stated"]
            for name, label in _SURVEY_FIELDS]
    return "<h2>Survey</h2>" + _table(["field", "value"], rows)


def _fmt_pct(value: float) -> str:
    return f"{value:.2f}" if np.isfinite(value) else "—"


def _ovality_figure(sections: list[ProfileSection]) -> str:
    plt = agg_pyplot()
    z = np.array([s.z_mm for s in sections])
    fig, ax = plt.subplots(figsize=(9, 3))
    for name, label in (("f1216_mean_min_pct", "ASTM F1216 (mean−min)/mean"),
                        ("f1216_max_mean_pct", "ASTM F1216 (max−mean)/mean"),
                        ("deflection_pct", "deflection (base−min)/base")):
        ax.plot(z, [getattr(s.figures, name) for s in sections], ".-", label=label)
    ax.set_xlabel("z of the ring (mm)")
    ax.set_ylabel("%")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def _ovality_section(data: ReportData) -> str:
    view = data.standards
    defs = _table(["column", "definition"], [[k, v] for k, v in DEFINITIONS.items()])
    if view is None or not view.sections:
        return defs + "<p>No diameter profile.</p>"
    measured = [s for s in view.sections if np.isfinite(s.figures.f1216_mean_min_pct)]
    if not measured:
        return (defs + "<p>Ovality not measured: the rings were fitted with the circle model "
                "(minimum = maximum diameter by construction), so no figure is reported.</p>")
    over = [s for s in measured if s.figures.f1216_mean_min_pct >= OVALITY_FLAG_PCT]
    rows = [[f"{s.frame:05d}", f"{s.z_mm:.1f}", f"{s.mean_id_mm:.3f}", f"{s.min_id_mm:.3f}",
             f"{s.max_id_mm:.3f}", *(_fmt_pct(getattr(s.figures, k)) for k in DEFINITIONS)]
            for s in over[:MAX_LISTED]]
    listed = (f"<p>{len(over)} of {len(measured)} sections with an ASTM F1216 ovality of at "
              f"least {OVALITY_FLAG_PCT:g} %{_more(len(over), 'ovality.csv')}.</p>")
    table = _table(["frame", "z (mm)", "mean ID (mm)", "min ID (mm)", "max ID (mm)",
                    *DEFINITIONS], rows) if rows else ""
    return (defs + f'<img alt="ovality along the pipe" src="{_ovality_figure(measured)}">'
            + listed + table)


def _more(n: int, csv_name: str) -> str:
    """A note that a list shows its first ``MAX_LISTED`` rows, and where the rest is."""
    if n <= MAX_LISTED:
        return ""
    return (f" (the first {MAX_LISTED} listed; all in <a href=\"{csv_name}\">{csv_name}"
            "</a>)")


def _listed(n: int, csv_name: str) -> str:
    """:func:`_more` as a paragraph of its own."""
    more = _more(n, csv_name)
    return f'<p class="note">{n} rows{more}.</p>' if more else ""


def _problems_section(data: ReportData) -> str:
    if not data.problems:
        return "<p>None.</p>"
    rows = [[f"{i:05d}" if i >= 0 else "run", m] for i, m in data.problems[:MAX_LISTED]]
    frames = len({i for i, _ in data.problems if i >= 0})
    return (f"<p>{len(data.problems)} notes on {frames} frames"
            f"{_more(len(data.problems), PROBLEMS_CSV)}.</p>" + _table(["frame", "problem"], rows))


def _exceedances(data: ReportData) -> str:
    """Frames whose diameter is outside the tolerance (listed, up to ``MAX_LISTED``)."""
    tol = data.tolerance_pct / 100 * data.nominal_diameter_mm
    out = [f for f in data.frames if np.isfinite(f.diameter_mm)
           and abs(f.diameter_mm - data.nominal_diameter_mm) > tol]
    head = (f"<p>{len(out)} of {len(data.frames)} frames with a diameter more than "
            f"{data.tolerance_pct:g} % from the nominal {data.nominal_diameter_mm:g} mm"
            f"{_more(len(out), 'profile.csv')}.</p>")
    rows = [[f"{f.frame:05d}", f"{f.z_mm:.1f}", f"{f.diameter_mm:.3f}",
             f"{f.diameter_mm - data.nominal_diameter_mm:+.3f}"] for f in out[:MAX_LISTED]]
    return head + (_table(["frame", "z (mm)", "D (mm)", "D − nominal (mm)"], rows)
                   if rows else "")


def _bins(data: ReportData) -> tuple[np.ndarray, float]:
    """Each frame's section index (``BIN_M`` along the pipe) and the first section's start."""
    z = _series(data, "z_mm")
    finite = z[np.isfinite(z)]
    start = float(np.floor(finite.min() / 1000.0)) * 1000.0 if finite.size else 0.0
    return np.where(np.isfinite(z), (z - start) // (BIN_M * 1000.0), -1).astype(int), start


def _range(values: np.ndarray, digits: int) -> str:
    values = values[np.isfinite(values)]
    if not values.size:
        return "—"
    return f"{values.mean():.{digits}f} ({values.min():.{digits}f}–{values.max():.{digits}f})"


def _summary_row(data: ReportData, k: int, start: float, members: np.ndarray) -> list[str]:
    z0, z1 = start + k * BIN_M * 1000.0, start + (k + 1) * BIN_M * 1000.0
    frames = [data.frames[i] for i in members]
    d = np.array([f.diameter_mm for f in frames], float)
    tilt = np.hypot([f.alpha_deg for f in frames], [f.beta_deg for f in frames])
    tol = data.tolerance_pct / 100 * data.nominal_diameter_mm
    ids = {f.frame for f in frames}
    defects = [x for x in data.defects if z0 <= x.z_mm < z1]
    holes = sum(1 for x in defects if x.kind == "hole")
    return [f"{z0 / 1000:.1f}–{z1 / 1000:.1f}", str(len(frames)),
            str(sum(f.ambiguous for f in frames)),
            str(len({i for i, _ in data.problems if i in ids})), _range(d, 2),
            str(int(np.sum(np.abs(d - data.nominal_diameter_mm) > tol))),
            f"{np.nanmax(tilt):.2f}" if np.isfinite(tilt).any() else "—",
            f"{holes} / {len(defects) - holes}"]


def _summary_section(data: ReportData) -> str:
    """One row per ``BIN_M`` of pipe: frames, flags, diameter, tilt, defects."""
    if not data.frames:
        return "<p>No frame has a pose.</p>"
    index, start = _bins(data)
    rows = [_summary_row(data, k, start, np.flatnonzero(index == k))
            for k in range(int(index.max()) + 1) if np.any(index == k)]
    return ('<p class="note">z of the camera, from the run\'s z origin; D as mean (min–max) '
            'of the rings.</p>'
            + _table(["z (m)", "frames", "ambiguous", "flagged", "D (mm)", "D out of tol.",
                      "max tilt (°)", "holes / spots"], rows))


def _tables_section(data: ReportData) -> str:
    items = "".join(f'<li><a href="{html.escape(name)}">{html.escape(name)}</a>: {what}</li>'
                    for name, what in TABLES if name in data.tables)
    return f"<ul>{items}</ul>" if items else "<p>None written.</p>"


def _review_note(data: ReportData) -> str:
    if data.review_href is None:
        return ""
    href = html.escape(data.review_href)
    return (f'<p>Review the mosaic with its defects, axes, a ruler and the source frames: '
            f'<a href="{href}">{href}</a> (read-only here; <code>pipestitch review OUT</code> '
            "to edit the observations).</p>")


def render_report(data: ReportData) -> str:
    """The report as one HTML string (no external resources); the per-frame tables are
    the CSV files beside it, linked (``data.tables``)."""
    figures = _table(["figure", "value"], [[k, v] for k, v in data.figures.items()])
    drawn = data.drawn or draw_track_figures(data)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(data.title)}</title>
<style>{_STYLE}</style></head><body>
<h1>{html.escape(data.title)}</h1>
{_survey_section(data)}
<h2>Summary per metre</h2>
{_summary_section(data)}
<h2>Unrolled wall</h2>
{_mosaic_section(data)}
{_review_note(data)}
<h2>Defects</h2>
<p class="note">Holes (red) and spots (amber), outlined on the mosaic; z and θ in the
mosaic's coordinates; clock: {_clock_note(data)}, clockwise looking along the survey
(right-hand axis of the mosaic).</p>
{_defect_table(data)}
<h2>Coded observations</h2>
{observation_section(data.standards)}
<h2>Diameter exceedances</h2>
{_exceedances(data)}
<h2>Ovality and deflection</h2>
{_ovality_section(data)}
<h2>Probe pose along the run</h2><img alt="pose track" src="{drawn['pose']}">
<h2>Diameter profile</h2><img alt="diameter profile" src="{drawn['profile']}">
<h2>Frames that failed, were skipped or stayed ambiguous</h2>{_problems_section(data)}
<h2>Processing</h2>{figures}
<h2>Per-frame tables</h2>{_tables_section(data)}
</body></html>
"""
