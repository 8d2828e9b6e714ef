"""``pipestitch export``: the coded observations of a run in an exchange format.

Registered on the main app by cli.py (``register``), which passes its error handler so
bad input still exits 2 with a one-line message.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from pipestitch.pipeline.progress import console

__all__ = ["CROWN_HELP", "register"]

CROWN_HELP = ("Mosaic theta (deg) of the crown, 12 o'clock: overrides imu.csv and a "
              "detected invert (default: imu.csv, else a sediment band / water line, else "
              "relative: the first frame's image up).")


def export(
    out: Annotated[Path, typer.Argument(help="Output folder of `pipestitch run`.")],
    fmt: Annotated[str, typer.Option("--format", "-f", help="en13508 (EN 13508-2 text "
                                     "exchange file), pacp7 (PACP 7 exchange tables, one CSV "
                                     "per table, in a folder), pacp-csv or json.")] = "en13508",
    dest: Annotated[Path | None, typer.Option("--out", "-o", help="File to write (default: "
                                              "OUT/observations.txt, _pacp.csv or .json; "
                                              "for pacp7 a folder, default OUT/pacp7).")
                    ] = None,
    crown_deg: Annotated[float | None, typer.Option("--crown-deg", help=CROWN_HELP)] = None,
    dataset: Annotated[Path | None, typer.Option(help="Dataset folder (for imu.csv, "
                                                 "probe.toml and survey.toml) if `run` did "
                                                 "not record it.")] = None,
    units: Annotated[str | None, typer.Option(help="Units of the PACP 7 tables: metric or "
                                              "imperial (feet, inches; IsImperial = 1). "
                                              "Default: survey.toml's, else metric.")
                     ] = None,
) -> None:
    """Export the run's coded observations (OUT/observations.csv, which you may edit).

    With --crown-deg or --dataset the run is re-coded first: rows whose ref starts with
    "auto:" are regenerated, every other row of observations.csv is kept as written.
    In the CSV files, text cells beginning with =, +, -, @, tab or CR get a leading '
    (spreadsheets do not run them as formulas); pipestitch reads them back without it.

    Example: pipestitch export out/test_piece --format pacp7 --units imperial
    """
    from pipestitch.pipeline.coding import EXPORTS, UNITS, export_run

    for option, value, allowed in (("--format", fmt, EXPORTS), ("--units", units, UNITS)):
        if value is not None and value not in allowed:
            console.print(f"[bold red]error:[/] {option}: expected one of "
                          f"{', '.join(allowed)}, got {escape(repr(value))}")
            raise typer.Exit(2)
    path = export_run(out, fmt, dest=dest, crown_deg=crown_deg, dataset=dataset, units=units)
    typer.echo(f"wrote {path}")


def register(app: typer.Typer, handle_errors: Callable) -> None:
    """Add the ``export`` command to ``app``."""
    app.command(name="export")(handle_errors(export))
