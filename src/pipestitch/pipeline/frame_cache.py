"""The decoded LED frames of one run, shared by its stages: in memory or in a spill file.

``pipestitch run`` reads each LED frame in the pose stage (ring reflectance,
photometric evidence), for the occluder mask, in every registration round and
for the stitch: four or five PNG decodes of the same file. So every frame is decoded
once and kept:

- in memory, when the whole run's LED frames fit a memory budget;
- else in a spill file: each decoded frame's pixels are appended, as stored, to an
  unlinked temporary file in a folder the caller names (the run's output folder, on
  the disk that takes the mosaic) and read back from there. Reading 1.2 MB back from
  the page cache takes a twentieth of a millisecond, a PNG decode of it ~9 ms. What
  the file holds is in the system's page cache, not in the process's resident memory,
  so memory does not grow with the run's length. The file takes at most a quarter of
  the folder's free space (and ``spill_budget_bytes``); frames beyond it, and all
  frames when no file can be made or written, are decoded each time they are read.

An LRU cache of part of a run would never hit: a run is read in full passes.

Each pass also asks whether a frame shows a picture at all
(:func:`pipestitch.camera.frames.blank_frame`); :func:`blank_led` asks once per decode.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from pipestitch.camera.frames import blank_frame

__all__ = ["CachedLedFrames", "blank_led"]

DEFAULT_BUDGET_BYTES = 512 * 2**20
SPILL_SHARE_OF_FREE = 0.25   # of the spill folder's free space the file may take
CLOSE_WAIT_S = 10.0          # closing waits this long at most for spill reads and writes


class CachedLedFrames:
    """A dataset whose ``read_led`` decodes each LED frame once: kept in memory when the
    run fits ``budget_bytes``, else in a spill file in ``spill_dir`` (when given).

    Whether the run fits is judged from the first frame read (all frames of a run have
    one size). Every other attribute is the wrapped dataset's. Thread-safe; frames are
    returned read-only (callers convert them, never write into them). :meth:`release`
    forgets the kept frames and closes (and so deletes) the spill file; :meth:`close`
    also closes the dataset.

    Parameters
    ----------
    dataset : Dataset
        What is wrapped (``read_led``, ``n_pairs`` and everything else).
    budget_bytes : int
        Memory the run's decoded frames may take.
    spill_dir : str or pathlib.Path, optional
        Folder of the spill file for a run that does not fit; None: such a run is
        decoded at every read.
    spill_budget_bytes : int, optional
        Most bytes the spill file may take (besides the share of the free space).
    """

    def __init__(self, dataset: Any, budget_bytes: int = DEFAULT_BUDGET_BYTES,
                 spill_dir: str | Path | None = None,
                 spill_budget_bytes: int | None = None) -> None:
        self._dataset = dataset
        self._budget = budget_bytes
        self._frames: OrderedDict[int, np.ndarray] = OrderedDict()
        self._bytes = 0
        self._mode: str | None = None   # "memory", "spill" or "off": on the first frame read
        self._spill_dir = spill_dir
        self._spill_budget = spill_budget_bytes
        self._file: BinaryIO | None = None
        self._spilled: dict[int, tuple[int, tuple[int, ...], np.dtype]] = {}
        self._end = 0
        self._in_flight = 0   # spill reads and writes under way: closing waits for them
        self._closing = False
        self._failed = False   # a write failed: the file is given up
        self._lock = threading.Condition()
        self._blank: dict[int, str] = {}   # blank_frame's verdict on each frame decoded

    def __getattr__(self, name: str) -> Any:
        return getattr(self._dataset, name)

    def read_led(self, index: int) -> np.ndarray:
        """LED frame ``index`` as stored (raises what the dataset raises)."""
        with self._lock:
            frame = self._frames.get(index)
            if frame is not None:
                self._frames.move_to_end(index)
                return frame
            where = self._spilled.get(index)
        if where is not None:
            frame = self._read_spilled(*where)
            if frame is not None:
                return frame
        frame = self._dataset.read_led(index)
        frame.flags.writeable = False
        with self._lock:
            self._blank.pop(index, None)   # a new decode: judged again when asked
            if self._mode is None:
                self._mode = self._choose_mode(frame.nbytes * self._dataset.n_pairs)
            if self._mode == "memory" and not self._closing and index not in self._frames:
                self._frames[index] = frame
                self._bytes += frame.nbytes
                while self._bytes > self._budget:   # a frame of another size: stay bounded
                    _, old = self._frames.popitem(last=False)
                    self._bytes -= old.nbytes
            offset = self._reserve(index, frame)
        if offset is not None:
            self._spill(index, offset, frame)
        return frame

    def blank(self, index: int, frame: np.ndarray) -> str:
        """:func:`~pipestitch.camera.frames.blank_frame` of LED frame ``index`` as
        :meth:`read_led` gave it (``frame``): judged once per decode, not at every read."""
        with self._lock:
            verdict = self._blank.get(index)
        if verdict is None:
            verdict = blank_frame(frame)
            with self._lock:
                self._blank[index] = verdict
        return verdict

    @property
    def spilled_bytes(self) -> int:
        """Bytes of the spill file given to frames so far (0 after a failed write)."""
        return self._end

    def close(self) -> None:
        """:meth:`release`, then close the dataset (a video's decoder)."""
        self.release()
        close = getattr(self._dataset, "close", None)
        if close is not None:
            close()

    def release(self, *, close_in_background: bool = False) -> None:
        """Forget the kept frames and close (and so delete) the spill file: for after the
        last pass that reads them. Later reads decode each time (idempotent).

        ``close_in_background``: the file is closed on a thread of its own (closing a
        file of gigabytes takes the system ~0.2 s to free its blocks); the frames kept
        in memory are let go at once either way.
        """
        file = None
        with self._lock:
            self._closing = True
            self._spilled.clear()
            self._frames.clear()
            self._bytes = 0
            # a read or write under way ends within milliseconds; one that an interrupt
            # left counted must not hold the run's exit
            # (one still counted then stays open until exit: its descriptor is not reused)
            if self._lock.wait_for(lambda: self._in_flight == 0, timeout=CLOSE_WAIT_S):
                file, self._file = self._file, None
        if file is None:
            return
        if close_in_background:
            threading.Thread(target=file.close, name="close the spill file").start()
        else:
            file.close()

    def _choose_mode(self, run_bytes: int) -> str:
        """Memory when the run fits the budget, else a spill file when one can be made
        (its budget set from the folder's free space), else nothing kept."""
        if run_bytes <= self._budget:
            return "memory"
        if (self._spill_dir is None or self._closing or self._spill_budget == 0
                or not hasattr(os, "pread")):
            return "off"   # (os.pread and os.pwrite are POSIX only)
        try:
            free = shutil.disk_usage(self._spill_dir).free
            self._file = tempfile.TemporaryFile(dir=self._spill_dir)
        except OSError:
            return "off"
        limit = int(SPILL_SHARE_OF_FREE * free)
        self._spill_budget = limit if self._spill_budget is None else min(limit,
                                                                          self._spill_budget)
        return "spill"

    def _reserve(self, index: int, frame: np.ndarray) -> int | None:
        """Where in the spill file ``frame`` goes (the lock is held); None: not kept."""
        if (self._mode != "spill" or self._closing or index in self._spilled
                or self._end + frame.nbytes > (self._spill_budget or 0)):
            return None
        offset, self._end = self._end, self._end + frame.nbytes
        return offset

    def _begin_io(self) -> int | None:
        """The spill file's descriptor, held open until :meth:`_end_io`; None when closed."""
        with self._lock:
            if self._file is None or self._closing or self._failed:
                return None
            self._in_flight += 1
            return self._file.fileno()

    def _end_io(self) -> None:
        with self._lock:
            self._in_flight -= 1
            self._lock.notify_all()

    def _spill(self, index: int, offset: int, frame: np.ndarray) -> None:
        """Write ``frame`` at ``offset``; readable from the file once written."""
        fd = self._begin_io()
        if fd is None:
            return
        try:
            written = os.pwrite(fd, np.ascontiguousarray(frame).data, offset) == frame.nbytes
        except OSError:
            written = False
        finally:
            self._end_io()
        with self._lock:
            if written and not (self._closing or self._failed):
                self._spilled[index] = (offset, frame.shape, frame.dtype)
            elif not written:
                self._give_up()

    def _give_up(self) -> None:
        """After a failed write (a full disk): no more reads or writes of the file, whose
        space is handed back once those under way have ended, so that the outputs still
        fit; frames are decoded at every read. The lock is held."""
        self._failed = True
        self._spill_budget, self._end = 0, 0
        self._spilled.clear()
        self._lock.wait_for(lambda: self._in_flight == 0, timeout=CLOSE_WAIT_S)
        if self._file is not None and self._in_flight == 0:
            try:
                os.ftruncate(self._file.fileno(), 0)
            except OSError:
                pass

    def _read_spilled(self, offset: int, shape: tuple[int, ...],
                      dtype: np.dtype) -> np.ndarray | None:
        """A spilled frame (read-only), or None when it cannot be read back."""
        size = int(np.prod(shape)) * dtype.itemsize
        fd = self._begin_io()
        if fd is None:
            return None
        try:
            data = os.pread(fd, size, offset)
        except OSError:
            return None
        finally:
            self._end_io()
        if len(data) != size:
            return None
        return np.frombuffer(data, dtype=dtype).reshape(shape)


def blank_led(dataset: Any, index: int, frame: np.ndarray) -> str:
    """Why LED frame ``index`` (``frame``, as ``dataset.read_led`` gave it) shows no
    picture, or "" (:func:`~pipestitch.camera.frames.blank_frame`): from the verdict a
    :class:`CachedLedFrames` keeps per decode, else judged now."""
    if isinstance(dataset, CachedLedFrames):
        return dataset.blank(index, frame)
    return blank_frame(frame)
