"""The report's figures: cropped as matplotlib's tight box would crop them, and the
same whether they were drawn ahead (in a thread) or while the report is rendered."""

from __future__ import annotations

import base64
import io

import cv2
import numpy as np

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


def test_mosaic_figure_is_cropped_as_a_tight_box_would_crop_it() -> None:
    """The crop is found with the image hidden (drawn once, not twice): same pixels."""
    data = _mosaic_data()
    ours = _decoded(html._mosaic_figure(data))
    plt = html.agg_pyplot()
    captured: list[object] = []
    real_png = html._png

    def keep(fig: object, **kwargs: object) -> str:
        captured.append(fig)
        buf = io.BytesIO()
        fig.savefig(buf, format="jpeg", dpi=html.FIGURE_DPI,  # type: ignore[attr-defined]
                    bbox_inches="tight", pil_kwargs={"quality": 90})
        plt.close(fig)
        return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode()

    html._png = keep   # the same figure, saved with matplotlib's own tight box
    try:
        tight = _decoded(html._mosaic_figure(data))
    finally:
        html._png = real_png
    assert captured and ours.shape == tight.shape
    assert np.array_equal(ours, tight)


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
