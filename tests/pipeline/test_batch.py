"""`pipestitch batch` on dask.distributed: real runs on a local cluster against the
plain `run` command, failures that never stop the others, retries, --scheduler, and
bad input."""

from __future__ import annotations

import csv
from pathlib import Path
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.errors import DatasetError
from pipestitch.pipeline import batch as batch_module
from pipestitch.pipeline.batch import ATTEMPT_MARK, output_names, run_batch

pytestmark = pytest.mark.slow   # starts dask clusters: slow on 2 cores


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def test_batch_cli_runs_each_dataset_like_run_and_survives_a_bad_one(
        tmp_path: Path, simulate_small) -> None:
    good = simulate_small(tmp_path / "in" / "good", "--scenario", "default", "--pairs", "2")
    bad = tmp_path / "in" / "bad"
    bad.mkdir()
    (bad / "probe.toml").write_text((good / "probe.toml").read_text())  # no frames/
    out = tmp_path / "out"
    runner = CliRunner()
    result = runner.invoke(app, ["batch", str(bad), str(good), "--out", str(out), "--quiet",
                                 "--workers", "1"])
    assert result.exit_code == 1, result.output
    rows = _rows(out / "batch_summary.csv")
    assert [(r["dataset"], r["status"]) for r in rows] == [("bad", "failed"), ("good", "ok")]
    assert "frames/ folder not found" in rows[0]["message"]
    assert rows[1]["pairs"] == "2" and rows[1]["attempts"] == "1"
    for name in ("bad", "good"):
        assert ATTEMPT_MARK in (out / name / "run.log").read_text()
    # The batch's outputs are those of a plain `run` of the same dataset.
    plain = tmp_path / "plain"
    assert runner.invoke(app, ["run", str(good), "--out", str(plain), "--quiet",
                               "--workers", "1"]).exit_code == 0
    for name in ("poses.csv", "profile.csv", "defects.csv"):
        assert (out / "good" / name).read_text() == (plain / name).read_text(), name


def test_batch_cli_rejects_missing_folders_and_bad_options(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["batch", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "nope" in result.output and "dataset folder not found" in result.output
    assert not (tmp_path / "o").exists()
    result = runner.invoke(app, ["batch", str(tmp_path), "--out", str(tmp_path / "o"),
                                 "--workers", "0"])
    assert result.exit_code == 2


@pytest.fixture()
def scheduler():
    """An in-process cluster (threads), so that a monkeypatched run is seen by workers."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        yield cluster.scheduler_address


def test_retries_and_crashes_on_an_existing_scheduler(tmp_path: Path, scheduler,
                                                      monkeypatch) -> None:
    calls: dict[str, int] = {}

    def fake_run(root, out, **_kw):
        name = Path(root).name
        calls[name] = calls.get(name, 0) + 1
        if name == "flaky" and calls[name] == 1:
            raise RuntimeError("worker hiccup")
        if name == "broken":
            raise RuntimeError("always fails")
        if name == "bad":
            raise DatasetError(Path(root) / "probe.toml", "missing")
        return SimpleNamespace(mosaic_failed=False, n_frames=7, n_placed=6, n_failed=1,
                               no_mosaic="")

    monkeypatch.setattr(batch_module, "run_dataset", fake_run)
    roots = []
    for name in ("flaky", "broken", "bad", "fine"):
        (tmp_path / name).mkdir()
        roots.append(tmp_path / name)
    results = run_batch(roots, tmp_path / "out", scheduler=scheduler, retries=2)
    by_name = {r.dataset: r for r in results}
    assert [r.dataset for r in results] == ["flaky", "broken", "bad", "fine"]
    assert (by_name["flaky"].status, by_name["flaky"].attempts) == ("ok", 2)
    assert by_name["broken"].status == "failed" and "always fails" in by_name["broken"].message
    assert calls["broken"] == 3  # 1 + 2 retries
    assert (by_name["bad"].status, calls["bad"]) == ("failed", 1)  # bad input: no retry
    assert (by_name["fine"].status, by_name["fine"].pairs, by_name["fine"].placed) == ("ok", 7, 6)
    assert len(_rows(tmp_path / "out" / "batch_summary.csv")) == 4


def test_output_names_are_unique() -> None:
    assert output_names([Path("a/run"), Path("b/run"), Path("c/x"), Path("d/run")]) == [
        "run", "run_2", "x", "run_3"]


def test_a_crash_is_one_console_line_and_its_traceback_goes_to_the_log(
        tmp_path: Path, scheduler, monkeypatch) -> None:
    import logging

    def fake_run(root, out, **_kw):
        if Path(root).name == "broken":
            raise RuntimeError("always fails")
        return SimpleNamespace(mosaic_failed=False, n_frames=3, n_placed=3, n_failed=0,
                               no_mosaic="")

    class Records(logging.Handler):
        def __init__(self) -> None:
            super().__init__(logging.DEBUG)
            self.messages: list[str] = []

        def emit(self, record: logging.LogRecord) -> None:
            self.messages.append(record.getMessage())

    seen = Records()   # what reaches the handlers of the dask worker's logger
    worker_logger = logging.getLogger("distributed.worker")
    worker_logger.addHandler(seen)
    monkeypatch.setattr(batch_module, "run_dataset", fake_run)
    for name in ("broken", "fine"):
        (tmp_path / name).mkdir()
    out = tmp_path / "out"
    try:
        result = CliRunner().invoke(app, ["batch", str(tmp_path / "broken"),
                                          str(tmp_path / "fine"), "--out", str(out),
                                          "--scheduler", scheduler, "--retries", "0",
                                          "--quiet"])
    finally:
        worker_logger.removeHandler(seen)
    assert result.exit_code == 1, result.output
    assert not [m for m in seen.messages if "Compute Failed" in m], seen.messages
    assert "Traceback" not in result.output
    failed = [line for line in result.output.splitlines() if line.startswith("failed:")]
    assert failed == [f"failed: broken: crashed: RuntimeError('always fails') "
                      f"(log: {out / 'broken' / 'run.log'})"], result.output
    log = (out / "broken" / "run.log").read_text()
    assert "Traceback" in log and "RuntimeError: always fails" in log


def test_batch_output_folders_are_checked_before_anything_runs(tmp_path: Path) -> None:
    runner = CliRunner()
    data = tmp_path / "in"
    (data / "a").mkdir(parents=True)
    (tmp_path / "afile").write_text("x")
    cases = [
        (tmp_path / "afile", str(tmp_path / "afile"), "an existing file"),
        (tmp_path / "afile" / "sub", str(tmp_path / "afile" / "sub"), "afile is a file"),
        (data, str(data / "a"), "inside the dataset"),   # OUT/a would be the dataset a
    ]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a").write_text("x")                 # where OUT/a goes
    cases.append((tmp_path / "out", str(tmp_path / "out" / "a"), "existing file"))
    for out, path, needle in cases:
        result = runner.invoke(app, ["batch", str(data / "a"), "--out", str(out), "--quiet"])
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert result.exit_code == 2, result.output
        assert len(lines) == 1 and path in lines[0] and needle in lines[0], result.output
    assert sorted(p.name for p in data.iterdir()) == ["a"]
    assert not (data / "a" / "a").exists() and not (data / "a" / "run.log").exists()


def test_ctrl_c_stops_the_workers_and_leaves_each_output_as_it_was(
        tmp_path: Path, simulate_small) -> None:
    """Ctrl-C reaches the whole process group (a terminal's): exit 130, one line, no
    dask traceback, no worker process left, and the datasets in flight keep their
    previous outputs byte for byte, with no staging folder left behind."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from pipestitch.pipeline.staging import LOCK, STAGING_PREFIX

    roots = [simulate_small(tmp_path / "in" / f"d{k}", "--pairs", "12", "--seed", str(k))
             for k in range(2)]
    out = tmp_path / "out"
    command = [sys.executable, "-m", "pipestitch.cli", "batch", *map(str, roots),
               "--out", str(out), "--quiet"]
    assert subprocess.run(command, capture_output=True, timeout=600).returncode == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != LOCK}
    # Started as from a terminal: Ctrl-C at its default disposition, whatever this test
    # process inherited (a CI job started in the background runs with SIGINT ignored,
    # which the batch, like any process, would then keep ignoring).
    terminal = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                "os.execv(sys.executable, [sys.executable, *sys.argv[1:]])")
    proc = subprocess.Popen([sys.executable, "-c", terminal, *command[1:]],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    deadline = time.monotonic() + 300
    while not list(out.glob(f"*/{STAGING_PREFIX}*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the batch ended before any run had started"
    os.killpg(proc.pid, signal.SIGINT)
    output = proc.communicate(timeout=120)[0].decode()
    assert proc.returncode == 130, output
    assert "Traceback" not in output and "interrupted" in output
    assert not _group_alive(proc.pid, within_s=10.0)   # no worker process is left
    assert not list(out.glob(f"*/{STAGING_PREFIX}*"))
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != LOCK}
    for root in roots:
        changed = {p.name for p in before.keys() | after.keys()
                   if p.parent == out / root.name and before.get(p) != after.get(p)}
        # The dataset's previous outputs as they were (its log says "interrupted"), or
        # a run that reached its commit while the cluster closed: a whole new set (of
        # the same data, so only the files that carry a time differ, both of them).
        assert changed <= {"run.log"} or {"report.html", "mosaic.ome.tif"} <= changed, changed


def _group_alive(pgid: int, within_s: float) -> bool:
    """Whether a process of the group ``pgid`` still runs after ``within_s`` seconds."""
    import os
    import time

    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return False
        time.sleep(0.1)
    return True
