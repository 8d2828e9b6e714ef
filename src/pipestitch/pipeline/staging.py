"""A run's outputs as one set: written into a staging folder, put in place only on success.

``pipestitch run DATASET --out OUT`` writes into ``OUT/.pipestitch-partial-PID`` (inside
OUT, so that putting the outputs in place is a rename on one filesystem). When
the run succeeds its outputs replace the previous run's, name by name (a folder such
as ``tiles/`` as a whole), and the previous run's outputs this run did not make are
removed, so the report always belongs to the mosaic next to it. Files a user added to
OUT are never touched. A run that fails, or is interrupted, leaves OUT exactly as it
was: its staging folder is removed, or kept (and named) when the failure is one whose
partial outputs are worth a look; so is one whose outputs could not all be put in place
(the error names both folders). Ctrl-C while the outputs are being put in place is
held until they all are.

A process killed outright (SIGKILL, power loss) while putting the outputs in place
cannot hold anything; for that the commit first writes a journal,
``OUT/.pipestitch-commit.json`` (atomically: it is there whole or not at all), naming
the staging folder, the outputs to move and those to remove. The next command that
writes or reads OUT (``run``, ``measure``, ``export``) finds it and finishes the
commit from the staging folder (:func:`finish_interrupted_commit`) before doing
anything else, so OUT never stays a mix of two runs.

Only one command writes into an OUT at a time: ``run``, ``measure``, ``export`` and the
review page's edits hold an advisory lock on ``OUT/.pipestitch-lock`` while they work
(:func:`out_lock`); a second one is refused at once (exit 2) with the holder named. The
operating system drops the lock when its holder ends, however it ends, so a killed run
never leaves OUT locked.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import threading
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from pipestitch.errors import DatasetError, StageError
from pipestitch.pipeline.check import check_out_folder_path

__all__ = ["JOURNAL", "LOCK", "RUN_OUTPUTS", "STAGING_PREFIX", "OutputBusy", "StagedOutput",
           "check_out_folder", "finish_interrupted_commit", "out_lock"]

# Everything `pipestitch run` may write into OUT (and earlier versions wrote).
RUN_OUTPUTS = ("poses.csv", "profile.csv", "defects.csv", "mosaic.png", "mosaic.json",
               "mosaic.ome.tif", "mosaic.tif", "tiles", "viewer.html", "report.html",
               "observations.csv", "standards.json", "ovality.csv", "problems.csv",
               "review.html", "observations.txt", "observations_pacp.csv",
               "observations.json")
# What a new run reads of the previous one in OUT (the user's observation rows).
CARRIED = ("observations.csv", "standards.json")
STAGING_PREFIX = ".pipestitch-partial-"
JOURNAL = ".pipestitch-commit.json"
LOCK = ".pipestitch-lock"


def check_out_folder(dataset: Path, out: Path) -> None:
    """Refuse an output folder that would overwrite the input or be read as it, or that
    cannot be a folder (:func:`pipestitch.pipeline.check.check_out_folder_path`).

    Raises
    ------
    DatasetError
        When ``out`` is inside the dataset, the dataset inside ``out``, a link to
        nothing, an existing file or cannot be created (exit 2, naming the paths).
    """
    data, target = dataset.resolve(), out.resolve()
    if target == data or data in target.parents:
        raise DatasetError(out, f"the output folder is inside the dataset {dataset}: its "
                                "outputs would overwrite or mix with the input; choose "
                                "--out outside it")
    if target in data.parents:
        raise DatasetError(out, f"the dataset {dataset} is inside the output folder: choose "
                                "--out elsewhere")
    if out.is_symlink() and not out.exists():
        raise DatasetError(out, "--out is a symbolic link to nothing")
    check_out_folder_path(out)


class StagedOutput:
    """The staging folder of one run into ``out`` (see the module docstring).

    Use as a context manager around the run: ``path`` is where to write; call
    :meth:`commit` when the run succeeded. Leaving the block without a commit removes
    the staging folder, unless :meth:`keep` was called.
    """

    def __init__(self, out: str | Path) -> None:
        self.out = Path(out)
        self.path = self.out / f"{STAGING_PREFIX}{os.getpid()}"
        self._done = False
        self._lock = out_lock(self.out, "run")

    def __enter__(self) -> StagedOutput:
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DatasetError(self.out, f"cannot write the output folder ({exc})") from None
        self._lock.__enter__()
        try:
            self._prepare()
        except BaseException:
            self._lock.__exit__(None, None, None)
            raise
        return self

    def _prepare(self) -> None:
        try:
            finish_interrupted_commit(self.out)
            shutil.rmtree(self.path, ignore_errors=True)
            self.path.mkdir()
            for name in CARRIED:   # the user's rows survive the re-coding, as in place
                if (self.out / name).is_file():
                    shutil.copy2(self.out / name, self.path / name)
        except OSError as exc:
            raise DatasetError(self.out, f"cannot write the output folder ({exc})") from None

    def keep(self) -> Path:
        """Keep the staging folder (a failed run's partial outputs) and return it."""
        self._done = True
        return self.path

    def commit(self) -> None:
        """Put the staged outputs in place of the previous run's, as one set."""
        with _interrupts_held():
            journal = self.out / JOURNAL
            try:
                made = sorted(p.name for p in self.path.iterdir())
                remove = [name for name in RUN_OUTPUTS if name not in made]
                _write_journal(journal, self.path.name, made, remove)
                _apply(self.out, self.path, made, remove)
            except OSError as exc:
                journal.unlink(missing_ok=True)
                kept = self.keep()
                raise StageError(f"the outputs could not all be put in place in {self.out} "
                                 f"({exc}); those not moved are in {kept}") from None
            shutil.rmtree(self.path, ignore_errors=True)
            journal.unlink(missing_ok=True)
            self._done = True

    def __exit__(self, *exc: object) -> None:
        try:
            if not self._done:
                shutil.rmtree(self.path, ignore_errors=True)
        finally:
            self._lock.__exit__(None, None, None)


class OutputBusy(DatasetError):
    """Another process holds the output folder's lock (:func:`out_lock`)."""


_held: Counter[tuple[str, int]] = Counter()   # locks held, by folder and thread (nesting)
_handles: dict[tuple[str, int], IO[str]] = {}
_held_guard = threading.Lock()
_BUSY = {errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES, errno.EDEADLK}


@contextmanager
def out_lock(out: str | Path, command: str) -> Iterator[None]:
    """Hold ``OUT``'s lock for the block: one writing command at a time per folder.

    Re-entrant within a thread (``export`` re-codes, ``measure`` measures then codes);
    another thread of the same process is refused like another process. The lock is
    the operating system's advisory lock on ``OUT/.pipestitch-lock`` (``flock``;
    ``msvcrt.locking`` of its first byte on Windows), released when the holder ends
    however it ends. On a file system that cannot lock at all the commands go
    unlocked. ``out`` must exist.

    Raises
    ------
    OutputBusy
        When another process or thread holds the lock (naming its command and PID).
    DatasetError
        When ``out`` is not a folder or the lock file cannot be made.
    """
    key = (str(Path(out).resolve()), threading.get_ident())
    with _held_guard:
        if not _held[key]:
            _handles[key] = _acquire(Path(out), command)
        _held[key] += 1
    try:
        yield
    finally:
        with _held_guard:
            _held[key] -= 1
            if not _held[key]:
                del _held[key]
                _release(_handles.pop(key))


def _acquire(out: Path, command: str) -> IO[str]:
    if not out.is_dir():
        raise DatasetError(out, "folder not found")
    path = out / LOCK
    try:
        handle = path.open("a+", encoding="utf-8")
    except OSError as exc:
        raise DatasetError(out, f"cannot write the output folder ({exc})") from None
    if not _try_lock(handle):
        holder = _holder(handle)
        handle.close()
        raise OutputBusy(out, f"another pipestitch command ({holder}) is writing into this "
                              "folder; wait for it to finish or choose another --out")
    handle.seek(0)
    handle.truncate()
    # byte 0 is the one locked on Windows (where a locked byte cannot be read): the
    # holder's name follows it
    handle.write(f"\npipestitch {command}, PID {os.getpid()}\n")
    handle.flush()
    return handle


def _holder(handle: IO[str]) -> str:
    try:
        handle.seek(1)
        return handle.read().strip() or "another process"
    except (OSError, ValueError):
        return "another process"


def _try_lock(handle: IO[str]) -> bool:
    """Lock ``handle`` without waiting: False when another holds it; True when locked,
    or when the file system has no locks at all."""
    try:
        _lock_now(handle)
    except OSError as exc:
        return exc.errno not in _BUSY
    return True


def _lock_now(handle: IO[str]) -> None:
    try:
        import fcntl
    except ImportError:   # Windows
        import msvcrt
        handle.seek(0)
        msvcrt.locking(handle.fileno(), msvcrt.LK_NBLCK, 1)
        return
    fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


def _release(handle: IO[str]) -> None:
    try:
        try:
            import fcntl
        except ImportError:   # Windows
            import msvcrt
            handle.seek(0)
            msvcrt.locking(handle.fileno(), msvcrt.LK_UNLCK, 1)
        else:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
    except OSError:
        pass   # not locked (no locks on this file system): closing is all there is
    finally:
        handle.close()


def finish_interrupted_commit(out: str | Path) -> bool:
    """Finish putting a killed run's outputs in place in ``out`` from its journal (see
    the module docstring); True when there was one. A journal that cannot be read or
    names no staging folder of ours is left alone (and reported as an error)."""
    out = Path(out)
    journal = out / JOURNAL
    if not journal.is_file():
        return False
    try:
        entry = json.loads(journal.read_text(encoding="utf-8"))
        staging = str(entry["staging"])
        made, remove = [str(n) for n in entry["made"]], [str(n) for n in entry["remove"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DatasetError(journal, f"unreadable record of an interrupted run ({exc}); "
                                    "remove it once OUT has been checked") from None
    if (not staging.startswith(STAGING_PREFIX) or not _is_plain_name(staging)
            or not all(map(_is_plain_name, made)) or not set(remove) <= set(RUN_OUTPUTS)):
        raise DatasetError(journal, "names paths outside the output folder; remove it once "
                                    "OUT has been checked")
    try:
        with _interrupts_held():
            _apply(out, out / staging, made, remove)
            shutil.rmtree(out / staging, ignore_errors=True)
            journal.unlink(missing_ok=True)
    except OSError as exc:
        raise StageError(f"an interrupted run's outputs could not be put in place in {out} "
                         f"({exc}); they are in {out / staging}") from None
    return True


def _is_plain_name(name: str) -> bool:
    return bool(name) and name not in (".", "..") and "/" not in name and "\\" not in name


def _write_journal(path: Path, staging: str, made: list[str], remove: list[str]) -> None:
    """The commit's journal, written to a temporary name in the staging folder (a process
    killed while writing it leaves nothing in OUT itself), flushed and renamed."""
    tmp = path.parent / staging / (path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as handle:
        json.dump({"staging": staging, "made": made, "remove": remove}, handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def _apply(out: Path, staging: Path, made: list[str], remove: list[str]) -> None:
    """Move the staged outputs in place and remove the previous run's others; safe to run
    again after an interruption (what was moved is no longer in ``staging``; a folder
    moved aside is merged back)."""
    for name in made:
        if (staging / name).exists() or (staging / name).is_symlink():
            _replace(staging / name, out / name)
        for aside in out.glob(f".{name}.old-*"):
            _merge_aside(aside, out / name)
    for name in remove:
        _remove(out / name)


def _merge_aside(aside: Path, dest: Path) -> None:
    """Move what an old folder held that its replacement does not into it; drop the rest."""
    if dest.is_dir():
        for entry in aside.iterdir():
            if not (dest / entry.name).exists():
                os.replace(entry, dest / entry.name)
    shutil.rmtree(aside, ignore_errors=True)


def _replace(src: Path, dest: Path) -> None:
    """Move ``src`` to ``dest``; a folder replaces the previous one as a whole (the old
    one is moved aside first, so ``dest`` is never a mix of both), but what the old one
    held that the new one does not (a file the user put in ``tiles/``) is moved over."""
    if dest.is_dir() and not dest.is_symlink():
        aside = dest.with_name(f".{dest.name}.old-{os.getpid()}")
        shutil.rmtree(aside, ignore_errors=True)
        os.replace(dest, aside)
        os.replace(src, dest)
        _merge_aside(aside, dest)
    else:
        os.replace(src, dest)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


@contextmanager
def _interrupts_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM for the block (main thread only); after it, an interrupt
    is raised as KeyboardInterrupt and a termination request re-sent to the process."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum)) for s in held}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if signal.SIGTERM in caught:
        os.kill(os.getpid(), signal.SIGTERM)
    if signal.SIGINT in caught:
        raise KeyboardInterrupt
