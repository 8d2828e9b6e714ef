"""``pipestitch batch``: many datasets on a dask.distributed cluster.

Each dataset runs :func:`pipestitch.pipeline.run.run_dataset` in a worker process
into ``OUT/<name>/`` with its own log, ``OUT/<name>/run.log``. A local cluster is
started by default (one single-threaded process per worker: the pipeline's own
threads would only compete for the same cores); an address uses an existing
scheduler. A dataset that fails never stops the others: bad input (a
:class:`PipestitchError`) is recorded at once, anything else (a crash, a lost
worker) is retried up to ``retries`` times by dask. ``OUT/batch_summary.csv`` lists
every dataset. It does not split one dataset across workers. A crash's traceback goes
to the dataset's run.log, not to the console (the worker's "Compute Failed" log
record of a pipestitch task is dropped).
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from pipestitch.errors import DatasetError, PipestitchError
from pipestitch.io.outputs import write_csv
from pipestitch.pipeline.check import check_out_folder_path
from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.staging import (
    STAGING_PREFIX,
    check_out_folder,
    finish_interrupted_commit,
    out_lock,
)
from pipestitch.pipeline.stitching import MosaicSettings

__all__ = ["BatchResult", "output_names", "run_batch", "run_one", "write_batch_summary"]

ATTEMPT_MARK = "=== pipestitch batch: attempt started"
TASK_PREFIX = "pipestitch-"   # the dask keys of batch tasks


class _QuietTaskFailures(logging.Filter):
    """Drop dask's "Compute Failed" record (with its traceback) for a batch task: the
    traceback is in the dataset's run.log and the batch reports the failure in one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        msg, args = record.msg, record.args
        return not (isinstance(msg, str) and msg.startswith("Compute Failed")
                    and isinstance(args, tuple) and bool(args)
                    and str(args[0]).startswith(TASK_PREFIX))


_QUIET = _QuietTaskFailures()


def _quiet_task_failures() -> None:
    """Install the filter on this (worker) process's dask worker logger, once."""
    worker_logger = logging.getLogger("distributed.worker")
    if _QUIET not in worker_logger.filters:
        worker_logger.addFilter(_QUIET)


@dataclass(frozen=True)
class BatchResult:
    """One dataset's outcome (one row of batch_summary.csv)."""

    dataset: str
    status: str  # "ok" | "failed"
    attempts: int
    seconds: float
    pairs: int
    placed: int
    failed_frames: int
    out: str
    log: str
    message: str


def output_names(roots: Sequence[Path]) -> list[str]:
    """Output folder names: the dataset folder's name, made unique with a suffix."""
    names: list[str] = []
    for root in roots:
        base = Path(root).resolve().name or "dataset"
        name, k = base, 2
        while name in names:
            name, k = f"{base}_{k}", k + 1
        names.append(name)
    return names


def _attempts(log: Path) -> int:
    try:
        return log.read_text(encoding="utf-8", errors="replace").count(ATTEMPT_MARK)
    except OSError:
        return 0


@contextlib.contextmanager
def _logging_to(log: Path) -> Iterator[None]:
    """Send this process's stderr (rich messages) and log records to ``log``.

    Process-wide redirection is safe because a batch worker runs one task at a time
    (threads_per_worker=1).
    """
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("a", encoding="utf-8") as handle:
        handler = logging.StreamHandler(handle)
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        root_logger = logging.getLogger()
        root_logger.addHandler(handler)
        try:
            with contextlib.redirect_stderr(handle), contextlib.redirect_stdout(handle):
                handle.write(f"{ATTEMPT_MARK} {time.strftime('%Y-%m-%dT%H:%M:%S')} ===\n")
                handle.flush()
                yield
        finally:
            root_logger.removeHandler(handler)


def run_one(root: str | Path, out: str | Path, *, threads: int = 1) -> BatchResult:
    """Run one dataset into ``out`` (log in ``out/run.log``); runs inside a worker.

    Bad input and processing failures are returned as a failed result; unexpected
    exceptions propagate so that the scheduler retries the task.
    """
    root, out = Path(root), Path(out)
    log = out / "run.log"
    start = time.perf_counter()
    _quiet_task_failures()
    with _logging_to(log):
        try:
            summary = run_dataset(root, out, settings=MosaicSettings(workers=threads),
                                  show_progress=False)
        except PipestitchError as exc:
            logging.getLogger(__name__).error("%s", exc)
            return _result(root, out, "failed", start, message=str(exc))
        except Exception:
            # the traceback for the log; the scheduler retries the task
            logging.getLogger(__name__).exception("run crashed")
            raise
    ok = not summary.mosaic_failed
    return _result(root, out, "ok" if ok else "failed", start, pairs=summary.n_frames,
                   placed=summary.n_placed, failed_frames=summary.n_failed,
                   message="" if ok else summary.no_mosaic)


def _result(root: Path, out: Path, status: str, start: float, *, pairs: int = 0,
            placed: int = 0, failed_frames: int = 0, message: str = "") -> BatchResult:
    log = out / "run.log"
    return BatchResult(root.name, status, _attempts(log), time.perf_counter() - start, pairs,
                       placed, failed_frames, str(out), str(log), message)


def _crashed(root: Path, out: Path, exc: BaseException) -> BatchResult:
    log = out / "run.log"
    message = " ".join(f"crashed: {exc!r}".split())   # one line
    return BatchResult(root.name, "failed", _attempts(log), 0.0, 0, 0, 0, str(out), str(log),
                       message)


def _check_roots(roots: Sequence[Path]) -> None:
    if not roots:
        raise DatasetError(None, "no dataset given")
    for root in roots:
        if not Path(root).is_dir():
            raise DatasetError(root, "dataset folder not found")


def _check_outputs(out_dir: Path, roots: Sequence[Path], outs: Sequence[Path]) -> None:
    """Every dataset's output folder can be written and is no dataset's folder, nor
    inside one (the outputs would overwrite or mix with the input)."""
    check_out_folder_path(out_dir)
    inputs = {Path(root).resolve(): Path(root) for root in roots}
    for root, out in zip(roots, outs, strict=True):
        check_out_folder(Path(root), out)   # also: an existing file where OUT/<name> goes
        target = out.resolve()
        for place in (target, *target.parents):
            if place in inputs:
                raise DatasetError(out, f"the output folder is inside the dataset "
                                        f"{inputs[place]}: choose --out outside it")


@contextlib.contextmanager
def _client(scheduler: str | None, workers: int) -> Iterator[object]:
    from distributed import Client, LocalCluster

    if scheduler is not None:
        with Client(scheduler, timeout="30s") as client:
            yield client
        return
    with _workers_ignore_ctrl_c():
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL)
    with cluster, Client(cluster) as client:
        yield client


@contextlib.contextmanager
def _workers_ignore_ctrl_c() -> Iterator[None]:
    """Start the local cluster's processes with SIGINT ignored (they inherit it): Ctrl-C
    reaches the whole process group, and only this process must act on it, by closing
    the cluster in order; a worker that died of it first would print dask's tracebacks."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def run_batch(roots: Sequence[str | Path], out_dir: str | Path, *,
              scheduler: str | None = None, workers: int = 2, retries: int = 1,
              threads: int = 1, on_done: Callable[[BatchResult], None] | None = None,
              ) -> list[BatchResult]:
    """Run every dataset on a dask.distributed cluster; results in the order given.

    Parameters
    ----------
    roots : sequence of Path
        Dataset folders (SPEC layout).
    out_dir : Path
        Each dataset's outputs go to ``out_dir/<name>/`` (see :func:`output_names`).
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``); default: a local
        cluster of ``workers`` single-threaded processes.
    retries : int
        Extra attempts for a task that raised or whose worker died.
    threads : int
        Pipeline threads inside each task.
    on_done : callable, optional
        Called with each result as it completes (progress display).

    Raises
    ------
    DatasetError
        If a dataset folder does not exist, or an output folder cannot be written or
        would be a dataset or inside one (nothing is run).
    """
    roots = [Path(r) for r in roots]
    _check_roots(roots)
    if workers < 1 or retries < 0 or threads < 1:
        raise ValueError(f"expected workers >= 1, retries >= 0, threads >= 1; got {workers}, "
                         f"{retries}, {threads}")
    outs = [Path(out_dir) / name for name in output_names(roots)]
    _check_outputs(Path(out_dir), roots, outs)

    results: dict[int, BatchResult] = {}
    token = uuid.uuid4().hex[:8]  # task keys unique on a scheduler shared by batches
    started = time.time()
    try:
        _submit_all(roots, outs, results, token, scheduler=scheduler, workers=workers,
                    retries=retries, threads=threads, on_done=on_done)
    except KeyboardInterrupt:
        if scheduler is None:   # a remote cluster's workers go on: their folders are theirs
            _clear_interrupted([o for k, o in enumerate(outs) if k not in results], started)
        raise
    ordered = [results[k] for k in range(len(roots))]
    write_batch_summary(Path(out_dir) / "batch_summary.csv", ordered)
    return ordered


def _submit_all(roots: list[Path], outs: list[Path], results: dict[int, BatchResult],
                token: str, *, scheduler: str | None, workers: int, retries: int,
                threads: int, on_done: Callable[[BatchResult], None] | None) -> None:
    """Run every dataset on the cluster, filling ``results`` as each completes."""
    from distributed import as_completed  # here: importing dask takes a while

    with _client(scheduler, workers) as client:
        futures = {client.submit(run_one, str(root), str(out), threads=threads,
                                 retries=retries, pure=False,
                                 key=f"{TASK_PREFIX}{token}-{k}-{out.name}"): k
                   for k, (root, out) in enumerate(zip(roots, outs, strict=True))}
        for future in as_completed(futures):
            k = futures[future]
            try:
                results[k] = future.result()
            except Exception as exc:  # a task that failed every attempt: record, go on
                results[k] = _crashed(roots[k], outs[k], exc)
            if on_done is not None:
                on_done(results[k])


def _clear_interrupted(outs: Sequence[Path], started: float) -> None:
    """After Ctrl-C, the runs that were in flight on the local workers (stopped with
    their cluster) leave each output folder as it was: a commit they began is finished
    from its journal, and the staging folders they made since ``started`` are removed (a
    failed run's staging folder kept by an earlier command is left alone). A folder
    whose lock someone still holds (a run that did not stop, another command) is left
    to it."""
    for out in outs:
        with contextlib.suppress(PipestitchError), out_lock(out, "batch"):
            finish_interrupted_commit(out)
            for staging in out.glob(f"{STAGING_PREFIX}*"):
                with contextlib.suppress(OSError):
                    if staging.stat().st_mtime >= started - 1.0:
                        shutil.rmtree(staging, ignore_errors=True)


def write_batch_summary(path: Path, results: Sequence[BatchResult]) -> Path:
    """``batch_summary.csv``: one row per dataset (atomic)."""
    columns = tuple(f.name for f in fields(BatchResult))
    rows = [[_cell(v) for v in asdict(r).values()] for r in results]
    return write_csv(path, columns, rows)


def _cell(value: object) -> object:
    return f"{value:.2f}" if isinstance(value, float) else value
