"""The report's figures: cropped as matplotlib's tight box would crop them, and the
same whether they were drawn ahead (in a thread) or while the report is rendered."""

from __future__ import annotations

import base64
import io

import cv2
import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from pipestitch.report import html
from pipestitch.report.html import FrameRow, ReportData, draw_track_figures, render_report


def _decoded(uri_or_bytes: str | bytes) -> np.ndarray:
    raw = (base64.b64decode(uri_or_bytes.split(",", 1)[1]) if isinstance(uri_or_bytes, str)
           else uri_or_bytes)
    return cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)


def _rows(n: int) -> list[FrameRow]:
    rng = np.random.default_rng(3)
    return [FrameRow(i, 5.0 * i, *rng.normal(0, 1, 4), 65.0 + rng.normal(0, 0.1), i == 3,
                     "continuity") for i in range(n)]


def _mosaic_data() -> ReportData:
    rng = np.random.default_rng(1)
    mosaic = cv2.GaussianBlur(rng.integers(0, 256, (600, 1500), dtype=np.uint8), (0, 0), 2)
    mosaic[:40] = 0   # no data: drawn in the face colour
    return ReportData("t", mosaic, 10.0, 0.1, 360 / 600, 65.0, _rows(12))


def _saved_by_matplotlib(fig: Figure, ax: Axes, rgb: np.ndarray) -> str:
    """The picture as matplotlib draws it: ``imshow`` over the axes and
    ``savefig(bbox_inches="tight")``."""
    ax.imshow(rgb, aspect="auto", extent=(*ax.get_xlim(), *ax.get_ylim()))
    buf = io.BytesIO()
    fig.savefig(buf, format="jpeg", dpi=html.FIGURE_DPI, bbox_inches="tight",
                pil_kwargs={"quality": 90})
    html.agg_pyplot().close(fig)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode()


def _smooth(picture: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(picture.astype(np.float32), (0, 0), 2.0)


def test_mosaic_figure_is_the_picture_matplotlib_draws(monkeypatch) -> None:
    """The mosaic laid under the figure's transparent rendering: matplotlib's own
    picture of it (imshow, tight box), the same size, text and axes, the image in the
    same place; its unseen pixels dark red."""
    data = _mosaic_data()
    ours = _decoded(html._mosaic_figure(data))
    monkeypatch.setattr(html, "_jpeg_under", _saved_by_matplotlib)
    theirs = _decoded(html._mosaic_figure(data))
    assert ours.shape == theirs.shape
    diff = np.abs(_smooth(ours) - _smooth(theirs))
    # resampling (area against matplotlib's), JPEG and lines snapped a pixel apart, the
    # same picture (0.83 and 7.5; the mosaic moved one of its pixels along: 1.18)
    assert np.mean(diff) < 1.0 and np.percentile(diff, 99) < 12
    # the unseen rows (the top 40 of 600) in the colour the report's note names
    bgr = np.array(html.UNSEEN_RGB[::-1], float)
    red = np.all(np.abs(ours.astype(float) - bgr) < 12, axis=2)
    rows = np.flatnonzero(red.mean(axis=1) > 0.5)
    assert rows.size > 0 and np.all(np.diff(rows) == 1)


def test_track_figures_drawn_ahead_give_the_same_report() -> None:
    rows = _rows(20)
    ahead = ReportData("", None, 0.0, 1.0, 1.0, 65.0, rows, tolerance_pct=2.0)
    drawn = draw_track_figures(ahead)
    assert set(drawn) == {"pose", "profile"}
    for uri in drawn.values():
        assert _decoded(uri).shape[0] > 100
    late = ReportData("t", None, 0.0, 1.0, 1.0, 65.0, rows, tolerance_pct=2.0)
    early = ReportData("t", None, 0.0, 1.0, 1.0, 65.0, rows, tolerance_pct=2.0, drawn=drawn)
    assert render_report(early) == render_report(late)
    # the report takes the figures it is given and draws no others in their place
    given = ReportData("t", None, 0.0, 1.0, 1.0, 65.0, rows,
                       drawn={"pose": "data:image/png;base64,POSE",
                              "profile": "data:image/png;base64,PROFILE"})
    page = render_report(given)
    assert "base64,POSE" in page and "base64,PROFILE" in page
    assert drawn["pose"] not in page and drawn["profile"] not in page


@pytest.mark.parametrize("shape", [(1513, 300), (500, 1), (2, 3000), (10, 10)])
def test_mosaic_figure_of_any_shape_fits_a_page(shape: tuple[int, int]) -> None:
    """A short run's tall mosaic keeps its aspect; a mosaic a few columns wide (or rows
    high) still gives a figure, at most MAX_FIGURE_HEIGHT_IN high (a JPEG, like
    matplotlib's canvas, ends at 65500 pixels)."""
    rng = np.random.default_rng(2)
    mosaic = rng.integers(1, 256, shape, dtype=np.uint8)
    data = ReportData("t", mosaic, 0.0, 0.1, 360 / shape[0], 65.0, _rows(3))
    picture = _decoded(html._mosaic_figure(data))
    assert picture is not None
    assert picture.shape[0] <= html.MAX_FIGURE_HEIGHT_IN * html.FIGURE_DPI
    if shape == (1513, 300):   # the image's own aspect: ~5 rows to a column
        dark = np.flatnonzero((picture.mean(axis=2) < 250).any(axis=1))
        tall = picture.shape[0] > 2.5 * picture.shape[1]
        assert dark.size and tall


def test_pose_track_draws_the_stated_two_sigma_bands() -> None:
    """Frames with a stated sigma get a shaded ±2 sigma band about each track; without
    one (nan) the track is drawn alone, as before."""
    from dataclasses import replace

    rows = _rows(12)
    plain = ReportData("t", None, 10.0, 0.1, 1.0, 65.0, rows)
    banded = replace(plain, frames=[replace(r, sigma=(0.3, 0.3, 0.2, 0.2)) for r in rows])
    nan = replace(plain, frames=[replace(r, sigma=(np.nan,) * 4) for r in rows])
    a, b, c = (_decoded(html._pose_figure(d)) for d in (plain, banded, nan))
    assert np.array_equal(a, c)
    changed = np.any(np.abs(a.astype(int) - b.astype(int)) > 30, axis=2)
    assert changed.mean() > 0.05   # the bands' area (measured: 0.19 of the picture)
