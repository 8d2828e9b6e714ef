"""``pipestitch mask``: write the occluder mask found from a dataset's LED frames.

Registered on the main app by :mod:`pipestitch.cli.app` (``register``), which passes
its error handler so bad input still exits 2 with a one-line message.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]


def mask(
    dataset: Annotated[Path, typer.Argument(help="Dataset folder (SPEC layout).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="PNG to write: 0 where the camera "
                                      "never sees the wall, 255 where it can.")],
    frames: Annotated[int, typer.Option(help="LED frames, spread over the run, to find "
                                        "the occluders from.")] = 11,
    video: Annotated[Path | None, typer.Option(help="Video of alternating laser/LED frames "
                                               "instead of DATASET/frames/.")] = None,
) -> None:
    """Find what never shows the wall (holder arm, mirror mount, lens rim) and write it.

    Occluders of any brightness are found by staying fixed in the image while the wall
    moves past. Inspect or edit the PNG, then name it in probe.toml ([probe] mask =
    "mask.png") for the runs to use it instead of finding it again.

    Example: pipestitch mask data/test_piece --out data/test_piece/mask.png
    """
    from pipestitch.pipeline.masking import run_mask

    summary = run_mask(dataset, out, video=video, frames=frames)
    typer.echo(f"wrote {summary.path}: {summary.occluded_fraction:.1%} of the image never "
               f"shows the wall (from {summary.n_frames} LED frames)")
    if summary.declared is not None:
        typer.echo(f"note: probe.toml names the mask {summary.declared}; runs use that one")


def register(app: typer.Typer, handle_errors: Callable) -> None:
    """Add the ``mask`` command to ``app``."""
    app.command(name="mask")(handle_errors(mask))
