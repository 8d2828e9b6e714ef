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
"""

from __future__ import annotations

import os
import shutil
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pipestitch.errors import DatasetError, StageError
from pipestitch.pipeline.check import check_out_folder_path

__all__ = ["RUN_OUTPUTS", "STAGING_PREFIX", "StagedOutput", "check_out_folder"]

# Everything `pipestitch run` may write into OUT (and earlier versions wrote).
RUN_OUTPUTS = ("poses.csv", "profile.csv", "defects.csv", "mosaic.png", "mosaic.json",
               "mosaic.ome.tif", "mosaic.tif", "tiles", "viewer.html", "report.html",
               "observations.csv", "standards.json", "ovality.csv")
# What a new run reads of the previous one in OUT (the user's observation rows).
CARRIED = ("observations.csv", "standards.json")
STAGING_PREFIX = ".pipestitch-partial-"


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

    def __enter__(self) -> StagedOutput:
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(self.path, ignore_errors=True)
            self.path.mkdir()
            for name in CARRIED:   # the user's rows survive the re-coding, as in place
                if (self.out / name).is_file():
                    shutil.copy2(self.out / name, self.path / name)
        except OSError as exc:
            raise DatasetError(self.out, f"cannot write the output folder ({exc})") from None
        return self

    def keep(self) -> Path:
        """Keep the staging folder (a failed run's partial outputs) and return it."""
        self._done = True
        return self.path

    def commit(self) -> None:
        """Put the staged outputs in place of the previous run's, as one set."""
        with _interrupts_held():
            made = {p.name for p in self.path.iterdir()}
            try:
                for name in sorted(made):
                    _replace(self.path / name, self.out / name)
                for name in RUN_OUTPUTS:
                    if name not in made:
                        _remove(self.out / name)
            except OSError as exc:
                kept = self.keep()
                raise StageError(f"the outputs could not all be put in place in {self.out} "
                                 f"({exc}); those not moved are in {kept}") from None
            shutil.rmtree(self.path, ignore_errors=True)
            self._done = True

    def __exit__(self, *exc: object) -> None:
        if not self._done:
            shutil.rmtree(self.path, ignore_errors=True)


def _replace(src: Path, dest: Path) -> None:
    """Move ``src`` to ``dest``; a folder replaces the previous one as a whole (the old
    one is moved aside first, so ``dest`` is never a mix of both), but what the old one
    held that the new one does not (a file the user put in ``tiles/``) is moved over."""
    if dest.is_dir() and not dest.is_symlink():
        aside = dest.with_name(f".{dest.name}.old-{os.getpid()}")
        shutil.rmtree(aside, ignore_errors=True)
        os.replace(dest, aside)
        os.replace(src, dest)
        for entry in aside.iterdir():
            if not (dest / entry.name).exists():
                os.replace(entry, dest / entry.name)
        shutil.rmtree(aside, ignore_errors=True)
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
