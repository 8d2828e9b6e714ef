"""The report in a real headless browser (Chromium via Playwright), when one is installed.

Skipped cleanly where there is no Chromium (Debian's package puts it at
/usr/bin/chromium; Playwright drives it, no browser download). Renders the report of
a small run to PNG, and asserts that the page logs no console error, loads no
external resource and shows the mosaic image at a real size.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app

sync_api = pytest.importorskip("playwright.sync_api")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed")]

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def test_report_renders_without_errors_and_shows_the_mosaic(tmp_path: Path,
                                                            simulate_small) -> None:
    root = simulate_small(tmp_path / "ds", "--scenario", "test_piece", "--pairs", "4")
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", str(root), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    errors: list[str] = []
    requests: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("request", lambda r: requests.append(r.url))
        page.goto((out / "report.html").as_uri())
        page.wait_for_load_state("load")
        box = page.locator("img#mosaic").bounding_box()
        natural = page.evaluate("document.getElementById('mosaic').naturalWidth")
        page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
        browser.close()
    assert errors == []
    assert all(u.startswith(("file:", "data:")) for u in requests), requests
    assert box is not None and box["width"] > 500 and box["height"] > 300
    assert natural > 500
    assert (tmp_path / "report.png").stat().st_size > 50_000
