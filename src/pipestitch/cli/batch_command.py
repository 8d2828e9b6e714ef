"""``pipestitch batch``: the command (registered on the app in cli.py).

Parses options, runs :func:`pipestitch.pipeline.batch.run_batch` with a progress bar
and prints the summary table; exit 0 when every dataset succeeded, 1 when any
failed, 2 for bad input (a missing folder, a bad option).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from pipestitch.pipeline.progress import console

if TYPE_CHECKING:
    from pipestitch.pipeline.batch import BatchResult

__all__ = ["batch"]


def batch(
    datasets: Annotated[list[Path], typer.Argument(help="Dataset folders (SPEC layout).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder: one sub-folder per "
                                      "dataset, with its run.log, and batch_summary.csv.")],
    scheduler: Annotated[str | None, typer.Option(
        help="Address of an existing dask scheduler (tcp://host:8786); default: a local "
             "cluster.")] = None,
    workers: Annotated[int, typer.Option(help="Worker processes of the local cluster "
                                         "(one dataset each at a time).")] = 2,
    retries: Annotated[int, typer.Option(help="Extra attempts for a dataset whose run "
                                         "crashed or whose worker died.")] = 1,
    threads: Annotated[int, typer.Option(help="Pipeline threads inside each dataset's "
                                         "run.")] = 1,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Run many datasets end to end on a dask.distributed cluster (`run` on each).

    Each dataset's outputs and log go to OUT/<name>/ (run.log); a failed dataset never
    stops the others; OUT/batch_summary.csv and a table summarise them, and each failed
    dataset gets one line with its reason (a crash's traceback is in its run.log). Exit 0
    when all succeeded, 1 when any failed, 2 for bad input or an output folder that
    cannot be written.

    Example: pipestitch batch data/run1 data/run2 --out out/night --workers 2
    """
    from pipestitch.pipeline.batch import run_batch

    if workers < 1 or retries < 0 or threads < 1:
        console.print("[bold red]error:[/] expected --workers >= 1, --retries >= 0, "
                      f"--threads >= 1; got {workers}, {retries}, {threads}")
        raise typer.Exit(2)
    columns = (TextColumn("[bold]batch"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console, disable=quiet) as progress:
        task = progress.add_task("batch", total=len(datasets))
        results = run_batch(datasets, out, scheduler=scheduler, workers=workers,
                            retries=retries, threads=threads,
                            on_done=lambda _r: progress.advance(task))
    console.print(summary_table(results))
    for r in results:   # one line each, never wrapped: the reason stays whole and greppable
        if r.status != "ok":
            console.print(f"[bold red]failed:[/] {escape(r.dataset)}: "
                          f"{escape(' '.join(r.message.split()) or r.status)} "
                          f"(log: {escape(r.log)})", soft_wrap=True, highlight=False)
    typer.echo(f"summary: {Path(out) / 'batch_summary.csv'}")
    if any(r.status != "ok" for r in results):
        raise typer.Exit(1)


def summary_table(results: list[BatchResult]) -> Table:
    """The rich table printed at the end of a batch (the reasons of failures follow it,
    one line each)."""
    table = Table(title="pipestitch batch")
    for name in ("dataset", "status", "attempts", "seconds", "pairs", "placed"):
        table.add_column(name, justify="left" if name in ("dataset", "status") else "right")
    for r in results:
        colour = "green" if r.status == "ok" else "red"
        table.add_row(escape(r.dataset), f"[{colour}]{r.status}[/]", str(r.attempts),
                      f"{r.seconds:.1f}", str(r.pairs), str(r.placed))
    return table
