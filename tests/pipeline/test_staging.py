"""A run's outputs replace the previous run's only as a whole set, and only on success;
the output folder can neither be the input nor hold it."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import pipestitch.pipeline.run as run_module
import pipestitch.pipeline.staging as staging
from pipestitch.errors import DatasetError, StageError
from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.staging import (
    JOURNAL,
    LOCK,
    RUN_OUTPUTS,
    STAGING_PREFIX,
    StagedOutput,
    check_out_folder,
    finish_interrupted_commit,
)


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file of ``folder`` but a failed run's kept staging folder and the lock."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != LOCK
            and not p.relative_to(folder).parts[0].startswith(STAGING_PREFIX)}


def _staging(out: Path) -> Path:
    return out / f"{STAGING_PREFIX}{os.getpid()}"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, simulate_small) -> Path:
    return simulate_small(tmp_path_factory.mktemp("staging") / "ds", "--pairs", "3",
                          "--seed", "2")


@pytest.fixture()
def previous(dataset: Path, tmp_path: Path) -> Path:
    """OUT holding a good run, and a file the user put there."""
    out = tmp_path / "out"
    run_dataset(dataset, out, show_progress=False)
    (out / "my_notes.txt").write_text("the user's own file")
    return out


def test_out_inside_the_dataset_or_around_it_is_refused(dataset: Path, tmp_path: Path) -> None:
    for bad in (dataset, dataset / "truth", dataset / "frames" / "x"):
        with pytest.raises(DatasetError, match="inside the dataset"):
            check_out_folder(dataset, bad)
    with pytest.raises(DatasetError, match="is inside the output folder"):
        check_out_folder(dataset, dataset.parent)
    (tmp_path / "file").write_text("x")
    with pytest.raises(DatasetError, match="existing file"):
        check_out_folder(dataset, tmp_path / "file")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    with pytest.raises(DatasetError, match="link to nothing"):
        check_out_folder(dataset, tmp_path / "dangling")
    with pytest.raises(DatasetError, match="inside the dataset"):
        run_dataset(dataset, dataset / "truth", show_progress=False)
    assert not (dataset / "truth" / "report.html").exists()


def test_a_failed_run_leaves_the_previous_run_as_it_was(dataset: Path, previous: Path,
                                                        tmp_path: Path) -> None:
    before = _snapshot(previous)
    bad = tmp_path / "bad"
    shutil.copytree(dataset, bad)
    for laser in (bad / "frames").glob("laser_*.png"):   # no ring: no pose, no mosaic
        cv2.imwrite(str(laser), np.zeros_like(cv2.imread(str(laser), cv2.IMREAD_UNCHANGED)))
    summary = run_dataset(bad, previous, show_progress=False)
    assert summary.mosaic_failed
    assert _snapshot(previous) == before
    kept = _staging(previous)
    assert summary.out == kept and (kept / "poses.csv").is_file()
    assert any(str(kept) in message for _, message in summary.problems)


def test_an_interrupted_run_leaves_the_previous_run_as_it_was(dataset: Path, previous: Path,
                                                              monkeypatch) -> None:
    before = _snapshot(previous)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    for stage in ("write_poses_csv", "render_report", "_coded"):   # early, late, last
        with monkeypatch.context() as patch:
            patch.setattr(run_module, stage, interrupted)
            with pytest.raises(KeyboardInterrupt):
                run_dataset(dataset, previous, show_progress=False)
        assert _snapshot(previous) == before
        assert not _staging(previous).exists()


def test_a_good_run_replaces_the_set_and_keeps_the_users_files(dataset: Path,
                                                               previous: Path) -> None:
    (previous / "mosaic.tif").write_bytes(b"an output of an older version")
    (previous / "tiles" / "my_tile_notes.txt").write_text("the user's file in tiles/")
    stale = next((previous / "tiles" / "mosaic_files").rglob("*.png"))
    stale.write_bytes(b"a tile of the previous run")
    summary = run_dataset(dataset, previous, show_progress=False)
    assert summary.out == previous and not summary.mosaic_failed
    assert (previous / "my_notes.txt").read_text() == "the user's own file"
    assert not (previous / "mosaic.tif").exists()
    assert (previous / "tiles" / "my_tile_notes.txt").read_text() == "the user's file in tiles/"
    assert stale.read_bytes() != b"a tile of the previous run"   # the new run's tile
    for name in ("poses.csv", "mosaic.png", "report.html", "tiles", "viewer.html"):
        assert (previous / name).exists()
    assert not _staging(previous).exists()


def test_every_output_a_run_writes_is_one_a_later_run_replaces(previous: Path) -> None:
    # A name missing from RUN_OUTPUTS outlives a later run that no longer writes it.
    written = {p.name for p in previous.iterdir()
               if not p.name.startswith(".") and p.name != "my_notes.txt"}
    assert {"poses.csv", "observations.txt", "observations.json"} <= written
    assert written <= set(RUN_OUTPUTS), written - set(RUN_OUTPUTS)


def test_ctrl_c_while_outputs_are_put_in_place_waits_for_the_whole_set(tmp_path: Path,
                                                                      monkeypatch) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "poses.csv").write_text("old")
    (out / "report.html").write_text("old")
    replace = staging._replace
    calls: list[str] = []

    def interrupted_replace(src: Path, dest: Path) -> None:
        calls.append(dest.name)
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGINT)   # Ctrl-C after the first file
        replace(src, dest)

    monkeypatch.setattr(staging, "_replace", interrupted_replace)
    with pytest.raises(KeyboardInterrupt), StagedOutput(out) as staged:
        (staged.path / "poses.csv").write_text("new")
        (staged.path / "report.html").write_text("new")
        staged.commit()
    assert calls == ["poses.csv", "report.html"]
    assert (out / "poses.csv").read_text() == (out / "report.html").read_text() == "new"


def test_outputs_that_cannot_be_put_in_place_are_kept_and_named(tmp_path: Path,
                                                               monkeypatch) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "poses.csv").write_text("old")

    def failing(src: Path, dest: Path) -> None:
        raise OSError(18, "Invalid cross-device link")

    monkeypatch.setattr(staging, "_replace", failing)
    with pytest.raises(StageError, match="could not all be put in place") as info, \
            StagedOutput(out) as staged:
        (staged.path / "poses.csv").write_text("new")
        staged.commit()
    assert str(staged.path) in str(info.value)
    assert (staged.path / "poses.csv").read_text() == "new"
    assert (out / "poses.csv").read_text() == "old"


def test_a_termination_request_waits_for_the_whole_set_too(tmp_path: Path,
                                                          monkeypatch) -> None:
    out = tmp_path / "out"
    resent: list[int] = []
    monkeypatch.setattr(staging.os, "kill", lambda pid, sig: resent.append(sig))
    replace = staging._replace

    def terminated_replace(src: Path, dest: Path) -> None:
        signal.raise_signal(signal.SIGTERM)   # held: recorded, not acted on
        replace(src, dest)

    monkeypatch.setattr(staging, "_replace", terminated_replace)
    with StagedOutput(out) as staged:
        (staged.path / "poses.csv").write_text("new")
        (staged.path / "report.html").write_text("new")
        staged.commit()
    assert (out / "poses.csv").read_text() == (out / "report.html").read_text() == "new"
    assert resent == [signal.SIGTERM]   # sent again once the set is in place


# Ctrl-C as in a terminal: a job started in the background (as CI may be) has SIGINT
# ignored, and its children inherit that.
_STARTED_THEN_CLI = ("import runpy, signal, sys; "
                     "signal.signal(signal.SIGINT, signal.default_int_handler); "
                     "sys.stdout.write('.'); sys.stdout.flush(); "
                     "runpy.run_module('pipestitch.cli', run_name='__main__', alter_sys=True)")


@pytest.mark.slow   # real processes, killed at several points of their run
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_a_killed_run_leaves_the_previous_run_byte_identical(dataset: Path, previous: Path,
                                                             sig: signal.Signals) -> None:
    import select
    import subprocess
    import sys
    import time

    before = _snapshot(previous)
    for delay in (1.0, 2.5, 4.0):   # imports, the pose pass, the mosaic and writing
        # `python -m pipestitch.cli`, with one byte written once Python itself has started:
        # the delay counts from there (an interrupt during Python's own start-up ends it
        # with "Fatal Python error" and exit 1, before any of pipestitch's code runs).
        proc = subprocess.Popen([sys.executable, "-c", _STARTED_THEN_CLI, "run", str(dataset),
                                 "--out", str(previous), "-q"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        assert proc.stdout is not None
        started, _, _ = select.select([proc.stdout], [], [], 120)
        if not started or proc.stdout.read(1) != b".":
            proc.kill()
            pytest.fail(f"the command did not start: {proc.communicate(timeout=120)[1]!r}")
        time.sleep(delay)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
        if proc.returncode == 0:   # finished before the signal: a new, whole set
            before = _snapshot(previous)
            continue
        after = _snapshot(previous)
        if after != before:
            # The run got as far as putting its outputs in place: either all of them
            # (its staging folder is gone; the signal came after) or, under SIGKILL,
            # which cannot be held, those moved before it (the rest wait in the folder).
            changed = {k.split("/")[0] for k in set(after) | set(before)
                       if after.get(k) != before.get(k)}
            # Under SIGKILL the commit's journal may be left beside the outputs: the record
            # the next command finishes the commit from (checked below).
            # So may a replaced folder's old copy, moved aside (`.tiles.old-*`).
            journal_left = (previous / JOURNAL).exists()
            assert not journal_left or sig == signal.SIGKILL, (delay, changed)
            aside = {k for k in changed if k.startswith(".") and ".old-" in k}
            assert not aside or sig == signal.SIGKILL, (delay, changed)
            assert changed - {JOURNAL} - aside <= set(RUN_OUTPUTS), (delay, changed)
            mine = previous / f"{STAGING_PREFIX}{proc.pid}"
            if not mine.exists() and journal_left:   # killed between the moves' end and its
                assert finish_interrupted_commit(previous)   # removal: nothing left to do
                assert not (previous / JOURNAL).exists()
            if mine.exists():
                assert sig == signal.SIGKILL, (delay, changed)
                pending = {p.name for p in mine.iterdir()}
                assert not changed & pending, (delay, changed)
                # The next command finishes the commit from the journal: the whole set.
                assert finish_interrupted_commit(previous)
                assert not mine.exists() and not (previous / JOURNAL).exists()
                assert all((previous / name).exists() for name in pending)
            before = _snapshot(previous)
            continue
        assert after == before, (delay, proc.returncode)
        if sig == signal.SIGINT and proc.returncode != -signal.SIGINT:
            # -SIGINT: the signal came before pipestitch's code ran (runpy importing the
            # package) or once it had ended; in between: one line, exit 130
            assert proc.returncode == 130 and b"Traceback" not in err, (delay, err[-2000:])


class _Killed(BaseException):
    """Stands for a process killed outright: nothing after it runs."""


def _killed_during_commit(out: Path, monkeypatch, after_moves: int) -> set[str]:
    """Stage a new set in ``out`` and stop the commit after ``after_moves`` outputs."""
    replace = staging._replace
    moves: list[str] = []

    def dying_replace(src: Path, dest: Path) -> None:
        if len(moves) == after_moves:
            raise _Killed
        moves.append(dest.name)
        replace(src, dest)

    monkeypatch.setattr(staging, "_replace", dying_replace)
    with pytest.raises(_Killed), StagedOutput(out) as staged:
        for name in ("defects.csv", "poses.csv", "report.html"):
            (staged.path / name).write_text("new")
        (staged.path / "tiles").mkdir()
        (staged.path / "tiles" / "0.png").write_text("new")
        staged._done = True      # a killed process never cleans up
        staged.commit()
    monkeypatch.setattr(staging, "_replace", replace)
    return set(moves)


@pytest.mark.parametrize("after_moves", [0, 1, 3])
def test_a_commit_killed_midway_is_finished_by_the_next_command(tmp_path: Path, monkeypatch,
                                                                after_moves: int) -> None:
    out = tmp_path / "out"
    out.mkdir()
    for name in ("defects.csv", "poses.csv", "report.html", "ovality.csv"):
        (out / name).write_text("old")
    (out / "tiles").mkdir()
    (out / "tiles" / "0.png").write_text("old")
    (out / "tiles" / "mine.txt").write_text("the user's")
    moved = _killed_during_commit(out, monkeypatch, after_moves)
    assert (out / JOURNAL).is_file() and len(moved) == after_moves
    assert {n for n in ("defects.csv", "poses.csv", "report.html")
            if (out / n).read_text() == "new"} == moved - {"tiles"}
    assert finish_interrupted_commit(out)
    for name in ("defects.csv", "poses.csv", "report.html", "tiles/0.png"):
        assert (out / name).read_text() == "new", name
    assert not (out / "ovality.csv").exists()            # the old run's, not made anew
    assert (out / "tiles" / "mine.txt").read_text() == "the user's"
    assert not (out / JOURNAL).exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".") and p.name != LOCK]
    assert not finish_interrupted_commit(out)            # nothing left to do


def test_a_folder_moved_aside_when_the_process_died_is_merged_back(tmp_path: Path) -> None:
    """Killed between moving the old tiles/ aside and moving the new one in."""
    out = tmp_path / "out"
    stage = out / f"{STAGING_PREFIX}4242"
    (stage / "tiles").mkdir(parents=True)
    (stage / "tiles" / "0.png").write_text("new")
    (out / ".tiles.old-4242").mkdir()
    (out / ".tiles.old-4242" / "0.png").write_text("old")
    (out / ".tiles.old-4242" / "mine.txt").write_text("the user's")
    (out / JOURNAL).write_text(json.dumps({"staging": stage.name, "made": ["tiles"],
                                           "remove": []}))
    assert finish_interrupted_commit(out)
    assert (out / "tiles" / "0.png").read_text() == "new"
    assert (out / "tiles" / "mine.txt").read_text() == "the user's"
    assert sorted(p.name for p in out.iterdir()) == ["tiles"]


@pytest.mark.parametrize("text", ["{not json", json.dumps({"staging": "../elsewhere",
                                                          "made": [], "remove": []}),
                                  json.dumps({"staging": f"{STAGING_PREFIX}1",
                                              "made": ["../../x"], "remove": []}),
                                  json.dumps({"staging": f"{STAGING_PREFIX}1", "made": [],
                                              "remove": ["my_notes.txt"]})])
def test_a_journal_that_cannot_be_trusted_is_refused_and_named(tmp_path: Path,
                                                               text: str) -> None:
    (tmp_path / JOURNAL).write_text(text)
    (tmp_path / "my_notes.txt").write_text("mine")
    with pytest.raises(DatasetError, match=JOURNAL):
        finish_interrupted_commit(tmp_path)
    assert (tmp_path / "my_notes.txt").read_text() == "mine"


_HOLDER = """
import sys, time
from pipestitch.pipeline.staging import out_lock
with out_lock(sys.argv[1], "run"):
    print("held", flush=True)
    time.sleep(60)
"""


def _hold_lock(out: Path) -> subprocess.Popen[str]:
    """Another process that holds OUT's lock until it is killed."""

    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_command_into_the_same_out_is_refused_while_the_first_works(
        dataset: Path, previous: Path) -> None:
    """Two commands writing into one OUT at once (run, measure, export, an edit in the
    review page): the second is refused naming the first (exit 2; the page gets 409) and
    leaves OUT as it was; once the first ends however it ends (here killed outright),
    the folder is free again."""
    import signal as signals

    from pipestitch.pipeline.coding import export_run
    from pipestitch.pipeline.measuring import measure_run
    from pipestitch.pipeline.review import Edit, EditError, edit_observations, read_observations

    before = _snapshot(previous)
    holder = _hold_lock(previous)
    try:
        with pytest.raises(DatasetError, match=rf"pipestitch run, PID {holder.pid}\)"):
            run_dataset(dataset, previous, show_progress=False)
        with pytest.raises(DatasetError, match="is writing into this folder"):
            measure_run(previous)
        with pytest.raises(DatasetError, match="is writing into this folder"):
            export_run(previous, "en13508")
        with pytest.raises(EditError, match="is writing into this folder") as refused:
            edit_observations(previous, Edit("delete", 0, None, read_observations(previous)[1]))
        assert refused.value.status == 409   # the page says: try again
        assert _snapshot(previous) == before
        assert not list(previous.glob(f"{STAGING_PREFIX}*"))
    finally:
        holder.send_signal(signals.SIGKILL)
        holder.wait()
    measure_run(previous)   # the killed holder's lock went with it


def test_the_lock_is_re_entrant_within_a_thread_and_refused_to_another(
        tmp_path: Path) -> None:
    """``export`` re-codes and ``measure`` measures then codes under one lock; another
    thread of the same process (a library user's) is refused as another process is, so
    that two runs never share one staging folder."""
    import threading

    out = tmp_path / "out"
    refused: list[BaseException] = []

    def second() -> None:
        try:
            with StagedOutput(out):
                pass
        except DatasetError as exc:
            refused.append(exc)

    with StagedOutput(out) as first, staging.out_lock(out, "measure"):
        (first.path / "poses.csv").write_text("first")
        thread = threading.Thread(target=second)
        thread.start()
        thread.join()
        assert (first.path / "poses.csv").read_text() == "first"
    assert len(refused) == 1 and "is writing into this folder" in str(refused[0])
    assert not staging._held
    with StagedOutput(out):   # free again
        pass


def test_a_process_killed_while_writing_the_journal_leaves_nothing_in_out(
        tmp_path: Path, monkeypatch) -> None:
    """Killed after the journal's temporary file was written, before it was renamed: the
    temporary file is in the staging folder, OUT holds only the previous run's outputs."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "poses.csv").write_text("old")

    def killed(fd: int) -> None:
        raise _Killed

    monkeypatch.setattr(staging.os, "fsync", killed)
    with pytest.raises(_Killed), StagedOutput(out) as staged:
        (staged.path / "poses.csv").write_text("new")
        staged.commit()
    visible = {p.name for p in out.iterdir() if not p.name.startswith(STAGING_PREFIX)}
    assert visible <= {"poses.csv", LOCK} and (out / "poses.csv").read_text() == "old"
    assert not finish_interrupted_commit(out)   # no journal: the previous run stands
