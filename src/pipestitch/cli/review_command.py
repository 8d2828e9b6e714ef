"""``pipestitch review``: the run's review page, served on this machine only.

Registered on the main app by app.py (``register``), which passes its error handler so
bad input still exits 2 with a one-line message.
"""

from __future__ import annotations

import webbrowser
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]


def review(
    out: Annotated[Path, typer.Argument(help="Output folder of `pipestitch run` (with a "
                                             "mosaic).")],
    port: Annotated[int, typer.Option(help="Port on 127.0.0.1 (0: any free port).")] = 0,
    dataset: Annotated[Path | None, typer.Option(help="Dataset folder, for the source frames, "
                                                 "if it is no longer where the run recorded "
                                                 "it.")] = None,
    browser: Annotated[bool, typer.Option("--browser/--no-browser",
                                          help="Open the page in the default browser.")] = True,
) -> None:
    """Review a run in the browser: the mosaic with its defects, axes, a ruler, the source
    frames, the profile and pose tracks, and observations to add, edit or delete.

    Serves OUT on 127.0.0.1 only (no internet needed) until Ctrl-C. Edits are checked by
    the server and saved to OUT/observations.csv, its exports and the observations of
    OUT/report.html; an edited or deleted auto: row stays so when the run is coded
    again. OUT/review.html, written too, shows the same page read-only from the file.

    Example: pipestitch review out/test_piece
    """
    from pipestitch.pipeline.review import write_review_page
    from pipestitch.pipeline.review_server import ReviewServer

    if not 0 <= port <= 65535:
        raise typer.BadParameter(f"--port: expected 0..65535, got {port}")
    if not out.is_dir():
        raise typer.BadParameter(f"{out}: not a folder (the output folder of `pipestitch run`)")
    if dataset is not None and not dataset.is_dir():
        raise typer.BadParameter(f"--dataset {dataset}: not a folder")
    write_review_page(out)
    server = ReviewServer(out, port=port, dataset=dataset)
    typer.echo(f"review page: {server.url} (read-only copy: {out / 'review.html'}); "
               "Ctrl-C to stop")
    if not server.frames.available:
        typer.echo(f"source frames not shown: {server.frames.problem} (use --dataset)")
    if browser:
        webbrowser.open(server.url)
    try:
        server.serve_forever()
    finally:
        server.httpd.server_close()


def register(app: typer.Typer, handle_errors: Callable) -> None:
    """Add the ``review`` command to ``app``."""
    app.command(name="review")(handle_errors(review))
