"""The pan-and-zoom viewer in a real headless browser (Chromium via Playwright).

Skipped cleanly where there is no Chromium (as test_report_browser.py). A synthetic
mosaic whose halves differ in brightness and which holds a 1-pixel checkerboard (a
pattern that averages away on every reduced level, so it can only be seen when the
full-resolution tiles are served) is written as tiles, opened from file:// and
checked: no console error, no request other than file:, the whole mosaic shown with
its dark half on the left, and the checkerboard resolved when zoomed in.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipestitch.io.tiles import write_pyramid
from pipestitch.pipeline.stitched_output import write_viewer

sync_api = pytest.importorskip("playwright.sync_api")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed")]

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
ROWS, COLS = 600, 2400
CHECK = (slice(200, 400), slice(1800, 2000))  # rows, cols of the checkerboard


def _mosaic() -> np.ndarray:
    image = np.full((ROWS, COLS), 40, dtype=np.uint8)
    image[:, COLS // 2:] = 200
    rr, cc = np.mgrid[CHECK]
    image[CHECK] = np.where((rr + cc) % 2 == 0, 0, 255).astype(np.uint8)
    return image


def _loaded(page) -> None:
    page.wait_for_function("() => { const v = window.pipestitchViewer;"
                           " const it = v && v.world.getItemAt(0);"
                           " return it && it.getFullyLoaded() && !v.viewport.isAnimating"
                           " ? true : false; }", timeout=20_000)
    page.wait_for_timeout(300)


def _shot(page) -> np.ndarray:
    from PIL import Image

    png = page.locator("#view").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=float)


def test_viewer_shows_the_mosaic_and_full_resolution_tiles(tmp_path: Path) -> None:
    image = _mosaic()
    blocks = ((c, image[:, c:c + 300]) for c in range(0, COLS, 300))
    info = write_pyramid(tmp_path / "mosaic.ome.tif", blocks, image.shape,
                         tiles_dir=tmp_path / "tiles")
    page_path = write_viewer(tmp_path, tmp_path / "tiles", mm_per_px=0.1, deg_per_px=0.6)
    assert info.dzi_path is not None and page_path.is_file()
    errors: list[str] = []
    requests: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 1200, "height": 700})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("request", lambda r: requests.append(r.url))
        page.goto(page_path.as_uri())
        _loaded(page)
        whole = _shot(page)
        page.evaluate("""() => { const v = window.pipestitchViewer;
            const item = v.world.getItemAt(0);
            const centre = item.imageToViewportCoordinates(1900, 300);
            v.viewport.zoomTo(item.imageToViewportZoom(4), null, true);
            v.viewport.panTo(centre, true); }""")
        _loaded(page)
        zoomed = _shot(page)
        page.screenshot(path=str(tmp_path / "viewer.png"))
        browser.close()
    assert errors == []
    assert all(u.startswith(("file:", "data:")) for u in requests), requests
    assert any("/mosaic_files/" in u for u in requests)
    # Whole view: the mosaic spans the width; sample the middle row band on each half
    # away from the checkerboard (which sits at 75-83 % of the width).
    band = whole[whole.shape[0] // 2 - 20: whole.shape[0] // 2 + 20]
    left = band[:, int(0.1 * band.shape[1]):int(0.4 * band.shape[1])]
    right = band[:, int(0.55 * band.shape[1]):int(0.7 * band.shape[1])]
    # Grey levels 40 and 200 drawn as they are (no smoothing, no colour management
    # beyond a few levels): two-sided bounds of +-6 grey levels.
    assert 34 <= np.median(left) <= 46
    assert 194 <= np.median(right) <= 206
    # Zoomed at 4 screen px per mosaic px inside the checkerboard: pixels alternate
    # 0/255 in 4 x 4 blocks; a reduced level would show a flat ~128 grey (std ~0).
    centre = zoomed[zoomed.shape[0] // 2 - 100: zoomed.shape[0] // 2 + 100,
                    zoomed.shape[1] // 2 - 100: zoomed.shape[1] // 2 + 100]
    assert centre.std() > 100
    assert np.mean((centre < 30) | (centre > 225)) > 0.9
