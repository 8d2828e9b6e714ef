"""Report and review page of a long run: size, open time and pan/zoom in Chromium.

A synthetic 1000-pair run (5 mm steps, a 65 mm pipe at 0.135 mm/px: a mosaic of
1513 x 37,000 px, its overview halved as `pipestitch run` does above 16 Mpx; 300
defects, 300 observations, 5 % of the frames flagged) is rendered by the report
(report/html.py, its viewer iframe included) and the review page
(report/review_page.py), written, and opened
from file:// in headless Chromium: the time to the load event, the file sizes, and
for the review page the frame times while it zooms and pans (requestAnimationFrame
intervals; the mosaic tiles are a flat grey pyramid of the full size).

Then the review page of a real run (the tiles `pipestitch run` wrote of a simulated
corroded pipe, ``--run OUT`` or simulated here with ``--real-pairs``), opened from
file:// and served by `pipestitch review`'s server: frame times while it zooms from
the whole mosaic to full resolution and back (wheel-like steps, animated) and while
it pans along the pipe at full resolution (a quarter of the view per step), with the
tiles loaded on the way.
Targets: report < 5 MB and opened in < 2 s; the review page smooth (95th percentile
frame time well under 50 ms).

Run: python bench/report.py [--quick] [--pairs N] [--run OUT | --real-pairs N]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np

from pipestitch.io.tiles import write_pyramid
from pipestitch.measure.defects import Defect
from pipestitch.pipeline.review import write_review_page
from pipestitch.pipeline.review_server import ReviewServer
from pipestitch.report.html import FrameRow, ReportData, render_report
from pipestitch.report.review_page import ReviewData, ReviewGrid, render_review
from pipestitch.report.viewer import render_viewer

STEP_MM, MM_PER_PX, ROWS = 5.0, 0.135, 1513
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _frames(n: int, rng: np.random.Generator) -> list[FrameRow]:
    return [FrameRow(i, i * STEP_MM, *rng.normal(0, 2, 2), *rng.normal(0, 3, 2),
                     65 + rng.normal(0, 0.4), bool(rng.random() < 0.02), "envelope")
            for i in range(n)]


def _defects(n: int, length_mm: float, rng: np.random.Generator) -> list[Defect]:
    return [Defect("hole" if k % 3 else "spot", float(rng.uniform(0, length_mm)),
                   float(rng.uniform(0, 360)), "3:00", 6.0, 28.3, 0, 0, 0, 0, -0.9, 1.0,
                   False) for k in range(n)]


def report_data(n: int, rng: np.random.Generator) -> ReportData:
    """The report of a synthetic ``n``-pair run (the overview as `run` would shrink it)."""
    length = n * STEP_MM + 35
    cols, factor = int(length / MM_PER_PX), 1
    while ROWS * cols / factor**2 > 16_000_000:
        factor += 1
    # a wall-like texture: smooth shading and a few grey levels of noise
    shape = (ROWS // factor, cols // factor)
    shade = 120 + 60 * np.sin(np.linspace(0, 40, shape[1]))[None, :] * np.cos(
        np.linspace(0, 6, shape[0]))[:, None]
    mosaic = np.clip(shade + rng.normal(0, 4, shape), 1, 255).astype(np.uint8)
    frames = _frames(n, rng)
    problems = [(f.frame, "pose ambiguous (mirror hypothesis not ruled out)")
                for f in frames if rng.random() < 0.05]
    return ReportData(f"pipestitch report: synthetic {n} pairs", mosaic, 0.0,
                      MM_PER_PX * factor, 360 / ROWS * factor, 65.0, frames, problems,
                      {"frame pairs": str(n)}, _defects(min(300, n), length, rng),
                      viewer_href="viewer.html", review_href="review.html",
                      tables=["poses.csv", "profile.csv", "problems.csv"])


def review_data(n: int, cols: int) -> ReviewData:
    """The review page of the same run (its tiles under tiles/)."""
    z = [i * STEP_MM for i in range(n)]
    source = {"Image": {"xmlns": "http://schemas.microsoft.com/deepzoom/2008", "Format": "png",
                        "Overlap": "0", "TileSize": "256", "Url": "tiles/mosaic_files/",
                        "Size": {"Width": str(cols), "Height": str(ROWS)}}}
    defects = [{"kind": "hole", "z_mm": k * 15.0, "theta_deg": (k * 37) % 360, "clock": "3:00",
                "diameter_mm": 6.0, "area_mm2": 28.3, "z_min_mm": k * 15.0 - 3,
                "z_max_mm": k * 15.0 + 3, "theta_min_deg": 0.0, "theta_max_deg": 10.0}
               for k in range(min(300, n))]
    return ReviewData("review", source, ReviewGrid(0.0, MM_PER_PX, 360 / ROWS, ROWS, cols,
                                                   2 * np.pi * 32.5 / ROWS),
                      270.0, "relative", 0.0, (-7.0, 34.0), 65.0, defects, [], "",
                      {"frame": list(range(n)), "z_mm": z, "roll_deg": [0.0] * n,
                       "alpha_deg": [1.0] * n, "beta_deg": [-1.0] * n, "dx_mm": [0.5] * n,
                       "dy_mm": [0.2] * n},
                      {"z_mm": [v + 16 for v in z], "diameter_mm": [65.0] * n,
                       "ovality": [0.001] * n})


def _tiles(folder: Path, cols: int) -> None:
    grey = np.full((ROWS, 2048), 128, np.uint8)
    blocks = ((c, grey[:, :min(2048, cols - c)]) for c in range(0, cols, 2048))
    write_pyramid(folder / "mosaic.ome.tif", blocks, (ROWS, cols), tiles_dir=folder / "tiles")


def _open_seconds(page, path: Path) -> float:
    start = time.perf_counter()
    page.goto(path.as_uri(), wait_until="load")
    return time.perf_counter() - start


_FRAME_TIMES = """async () => { const v = window.pipestitchReview.viewer, times = [];
  let last = performance.now(), run = true;
  const tick = (t) => { times.push(t - last); last = t; if (run) requestAnimationFrame(tick); };
  requestAnimationFrame(tick);
  for (let k = 0; k < 40; k++) {
    v.viewport.zoomBy(k % 8 < 4 ? 1.6 : 0.625); v.viewport.panBy(new OpenSeadragon.Point(0.02, 0));
    await new Promise((r) => setTimeout(r, 60)); }
  run = false; times.sort((a, b) => a - b);
  return [times[Math.floor(times.length / 2)], times[Math.floor(times.length * 0.95)]]; }"""


def _chromium() -> tuple[object, str] | None:
    """(playwright's sync_playwright, the Chromium executable), or None without them."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return None
    return (sync_playwright, chromium) if chromium is not None else None


def _browser_figures(folder: Path) -> dict[str, float] | None:
    found = _chromium()
    if found is None:
        return None
    sync_playwright, chromium = found
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        report_s = min(_open_seconds(page, folder / "report.html") for _ in range(3))
        review_s = min(_open_seconds(page, folder / "review.html") for _ in range(3))
        page.wait_for_timeout(500)
        median, p95 = page.evaluate(_FRAME_TIMES)
        browser.close()
    return {"report_s": report_s, "review_s": review_s, "frame_ms": median, "frame95_ms": p95}


# --- the review page of a real run ---------------------------------------------------------

def simulated_run(root: Path, pairs: int) -> Path:
    """Simulate ``pairs`` half-size pairs of the corrosion scenario and run them; OUT."""
    cli = [sys.executable, "-m", "pipestitch.cli.app"]
    ds, out = root / "ds", root / "out"
    subprocess.run([*cli, "simulate", "--scenario", "corrosion", "--pairs", str(pairs),
                    "--size", "half", "--quiet", "--out", str(ds)], check=True,
                   stdout=subprocess.DEVNULL)
    subprocess.run([*cli, "run", str(ds), "--out", str(out), "--quiet"], check=True,
                   stdout=subprocess.DEVNULL)
    return out


# Zoom from the whole mosaic to 1:1 and back around a point at 30 % of the run, in wheel
# steps of 1.25 (OpenSeadragon animates each), twice; then pan along the pipe at 1:1 by
# a quarter of the view per step. requestAnimationFrame intervals of each phase, the
# tiles loaded and the time until the view is complete after the last step.
_PAN_ZOOM = """async ([maxSteps, pauseMs]) => {
  const v = window.pipestitchReview.viewer, it = v.world.getItemAt(0), OSDP = OpenSeadragon.Point;
  const wait = (ms) => new Promise((r) => setTimeout(r, ms));
  let tiles = 0, moving = false;
  v.addHandler("tile-loaded", () => { tiles += 1; });
  v.addHandler("animation-start", () => { moving = true; });
  v.addHandler("animation-finish", () => { moving = false; });
  async function settle() {      // the move's animation over and every tile of the view drawn
    const t0 = performance.now();
    await wait(50);
    while ((moving || !it.getFullyLoaded()) && performance.now() - t0 < 30000) await wait(20);
    return performance.now() - t0; }
  async function record(moves) {
    const times = []; let last = performance.now(), run = true;
    const tick = (t) => { times.push(t - last); last = t; if (run) requestAnimationFrame(tick); };
    requestAnimationFrame(tick);
    for (const move of moves) { move(); await wait(pauseMs); }
    const settled = await settle();
    run = false;
    return { times, settled };
  }
  const size = it.getContentSize(), full = it.imageToViewportZoom(1);
  v.viewport.goHome(true); await settle();
  const at = it.imageToViewportCoordinates(size.x * 0.3, size.y / 2);
  const n = Math.max(1, Math.ceil(Math.log(full / v.viewport.getZoom()) / Math.log(1.25)));
  const zoomMoves = [];
  for (let r = 0; r < 2; r++) {
    for (let k = 0; k < n; k++) zoomMoves.push(() => v.viewport.zoomBy(1.25, at));
    for (let k = 0; k < n; k++) zoomMoves.push(() => v.viewport.zoomBy(0.8, at));
  }
  const zoom = await record(zoomMoves);
  v.viewport.zoomTo(full, null, true);
  const view = v.viewport.getBounds(true);
  v.viewport.panTo(new OSDP(view.width / 2, at.y), true); await settle();
  const step = view.width / 4, room = 1 - view.width;
  const steps = Math.max(1, Math.min(maxSteps, Math.floor(room / step)));
  const pan = await record(Array.from({ length: steps },
    () => () => v.viewport.panBy(new OSDP(step, 0))));
  const tilesSeen = tiles;
  return { zoom, pan, tiles: tilesSeen, zoomSteps: zoomMoves.length, panSteps: steps };
}"""


def frame_stats(times: list[float]) -> dict[str, float]:
    """Median, 95th percentile and longest frame (ms) and the share over 50 ms."""
    t = np.sort(np.asarray(times[1:] or [0.0], float))     # the first interval is partial
    return {"median": float(np.median(t)), "p95": float(np.percentile(t, 95)),
            "max": float(t[-1]), "slow_pct": float(100 * np.mean(t > 50)), "frames": t.size}


def _pan_zoom(page, url: str, max_steps: int) -> dict[str, object]:
    page.goto(url, wait_until="load")
    page.wait_for_function("() => { const v = window.pipestitchReview.viewer;"
                           " return v.world.getItemAt(0) !== undefined; }", timeout=30_000)
    found = page.evaluate(_PAN_ZOOM, [max_steps, 100])
    return {"zoom": frame_stats(found["zoom"]["times"]), "pan": frame_stats(found["pan"]["times"]),
            "zoom_settle_ms": found["zoom"]["settled"], "pan_settle_ms": found["pan"]["settled"],
            "tiles": found["tiles"], "zoom_steps": found["zoomSteps"],
            "pan_steps": found["panSteps"]}


def real_tiles_figures(out: Path, max_steps: int) -> dict[str, dict[str, object]] | None:
    """Pan/zoom frame times of ``out``'s review page, from file:// and served."""
    found = _chromium()
    if found is None:
        return None
    sync_playwright, chromium = found
    write_review_page(out)
    figures = {}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=FLAGS)
        for how in ("file", "served"):
            with ReviewServer(out) if how == "served" else nullcontext() as server:
                page = browser.new_page(viewport={"width": 1400, "height": 900})
                url = server.url if server is not None else (out / "review.html").as_uri()
                figures[how] = _pan_zoom(page, url, max_steps)
                page.close()
        browser.close()
    return figures


def _tile_summary(out: Path) -> str:
    full = json.loads((out / "mosaic.json").read_text())["full_resolution"]
    levels = sorted((out / "tiles" / "mosaic_files").iterdir(), key=lambda d: int(d.name))
    count = sum(1 for level in levels for _ in level.iterdir())
    return (f"mosaic {full['n_rows']} x {full['n_cols']} px, {len(levels)} levels, "
            f"{count} tiles")


def _print_real(out: Path, figures: dict[str, dict[str, object]]) -> None:
    print(f"real tiles: {out} ({_tile_summary(out)})")
    for how, f in figures.items():
        for phase in ("zoom", "pan"):
            s = f[phase]
            print(f"review {phase} on real tiles ({how}, {f[phase + '_steps']} steps): frame "
                  f"time median {s['median']:.1f} ms, 95th percentile {s['p95']:.1f} ms, max "
                  f"{s['max']:.0f} ms, {s['slow_pct']:.1f} % of {s['frames']} frames over 50 ms; "
                  f"complete {f[phase + '_settle_ms'] / 1000:.2f} s after the last step")
        print(f"  tiles loaded ({how}): {f['tiles']}")


def synthetic(n: int, folder: Path) -> None:
    """Report and review page of a synthetic ``n``-pair run, written into ``folder``."""
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    report = render_report(report_data(n, rng))
    render_s = time.perf_counter() - start
    (folder / "report.html").write_text(report, encoding="utf-8")
    cols = int((n * STEP_MM + 35) / MM_PER_PX)
    _tiles(folder, cols)
    review_page = review_data(n, cols)
    (folder / "review.html").write_text(render_review(review_page), encoding="utf-8")
    (folder / "viewer.html").write_text(render_viewer(review_page.tiles), encoding="utf-8")
    size = (folder / "report.html").stat().st_size / 1e6
    review = (folder / "review.html").stat().st_size / 1e6
    print(f"{n} pairs: report {size:.2f} MB (rendered in {render_s:.1f} s), "
          f"review page {review:.2f} MB, mosaic {ROWS} x {cols} px")
    figures = _browser_figures(folder)
    if figures is None:
        print("no Chromium/Playwright: open times not measured")
        return
    print(f"open in Chromium (load event, best of 3): report {figures['report_s']:.2f} s, "
          f"review page {figures['review_s']:.2f} s")
    print(f"review zoom/pan frame time: median {figures['frame_ms']:.1f} ms, "
          f"95th percentile {figures['frame95_ms']:.1f} ms")


def real_run(args: argparse.Namespace, tmp: Path) -> None:
    """The review page of a real run: ``--run OUT``, else one simulated here."""
    if args.run is not None:
        out = args.run
    else:
        pairs = 8 if args.quick else args.real_pairs
        start = time.perf_counter()
        out = simulated_run(tmp / "real", pairs)
        print(f"simulated and ran {pairs} pairs (corrosion, half size) in "
              f"{time.perf_counter() - start:.0f} s")
    figures = real_tiles_figures(out, 6 if args.quick else 60)
    if figures is None:
        print("no Chromium/Playwright: pan/zoom on real tiles not measured")
        return
    _print_real(out, figures)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="50 synthetic pairs and a real run of 8 pairs (smoke run)")
    parser.add_argument("--pairs", type=int, default=1000)
    parser.add_argument("--run", type=Path, default=None,
                        help="a `pipestitch run` OUT whose tiles the review page pans over")
    parser.add_argument("--real-pairs", type=int, default=300,
                        help="pairs to simulate and run for the real tiles (without --run)")
    parser.add_argument("--only", choices=("synthetic", "real"), default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="pipestitch-bench-report-") as tmp:
        if args.only != "real":
            synthetic(50 if args.quick else args.pairs, Path(tmp))
        if args.only != "synthetic":
            real_run(args, Path(tmp))


if __name__ == "__main__":
    main()
