"""Image files decoded ahead on one thread, for a reader that comes later.

:class:`DecodeAhead` decodes a list of files in order while the caller does something
else that leaves a core free (a command importing its stages); OpenCV releases the GIL
while it decodes, so the two overlap. :func:`pipestitch.io.images.read_image` then takes
a file's pixels from here (:func:`take`) instead of decoding it again, after the same
checks it makes on a file it decodes itself, so what it returns, and every error it
raises, is the same either way. Only one list is decoded ahead at a time.

A file is taken only when it is still the regular file it was when it was decoded
(device, inode, size, modification and change times). The thread stops at the end of
the list, at ``budget_bytes`` of decoded pixels (judged from each file's header before
it is decoded), when the reader has asked twice for the file it is decoding or one of
the next few (the reader has caught up: from there on decoding ahead would only
duplicate its work), or at :meth:`stop`; it never keeps a file the reader has already
asked for. Once it has stopped, files well behind the furthest one taken are dropped,
and all at :meth:`stop`, so nothing decoded ahead outlives its use.
"""

from __future__ import annotations

import os
import stat
import threading
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

import cv2
import numpy as np

from pipestitch.io.filebytes import file_bytes

__all__ = ["DecodeAhead", "take"]

# The reader has caught up when it has asked this many times for a file this close ahead
# of the thread (once could be a reader on another thread sampling the run); once the
# thread has stopped, files this far behind the furthest one taken are dropped (readers
# on a few threads ask slightly out of order).
CAUGHT_UP_FILES = 4
CAUGHT_UP_TIMES = 2
KEPT_BEHIND = 16


Stamp = tuple[int, int, int, int, int]


def _stamp(path: Path) -> Stamp | None:
    """What identifies a regular file's content here (device, inode, size, modification
    and change times); None for anything else (a FIFO or a device is never read ahead)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    if not stat.S_ISREG(st.st_mode):
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


class DecodeAhead:
    """Decode ``paths`` in order on one thread (a context manager: started on entry,
    stopped and joined on exit).

    Parameters
    ----------
    paths : sequence of pathlib.Path
        The files, in the order the reader will ask for them.
    budget_bytes : int
        Most bytes of decoded pixels to produce (a file that would pass it, judged from
        its header before decoding, ends the work).
    """

    def __init__(self, paths: Sequence[Path], budget_bytes: int) -> None:
        self._paths = [Path(p) for p in paths]
        self._position = {p: k for k, p in enumerate(self._paths)}
        self._budget = budget_bytes
        self._done: dict[Path, tuple[Stamp, tuple[int, int], np.ndarray]] = {}
        self._reached = 0           # files before this one were decoded or passed over
        self._skip: set[int] = set()   # asked for before the thread reached them
        self._caught_up = 0
        self._taken = -1            # the furthest file taken
        self._stopped = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._decode_all, name="decode-ahead",
                                        daemon=True)

    def __enter__(self) -> DecodeAhead:
        global _active
        with _registry_lock:
            _active = self
        try:
            self._thread.start()
        except BaseException:   # e.g. Ctrl-C while the thread starts
            self.stop()
            raise
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def stop(self) -> None:
        """Stop decoding, wait for the thread (at most the file it is decoding; a Ctrl-C
        meanwhile is raised once it has ended), release what was not taken."""
        global _active
        self._stopped.set()
        interrupted: BaseException | None = None
        try:
            while self._thread.ident is not None:   # started (is_alive() can be wrong
                try:                                # after an interrupted join)
                    self._thread.join()
                    break
                except KeyboardInterrupt as exc:
                    interrupted = exc
        finally:
            with _registry_lock:
                if _active is self:
                    _active = None
            with self._lock:
                self._done.clear()
        if interrupted is not None:
            raise interrupted

    @property
    def decoded(self) -> int:
        """Files decoded and not yet taken or dropped."""
        with self._lock:
            return len(self._done)

    @property
    def running(self) -> bool:
        """Whether the thread still decodes."""
        return self._thread.is_alive()

    def take(self, path: Path) -> tuple[tuple[int, int], np.ndarray] | None:
        """A file's pixels if they were decoded ahead.

        Parameters
        ----------
        path : pathlib.Path
            The file, as it was listed.

        Returns
        -------
        tuple or None
            (declared (width, height), pixels) when ``path`` was decoded ahead and is
            unchanged since (each file is given out once); None otherwise: the caller
            reads the file itself.
        """
        k = self._position.get(path)
        if k is None:
            return None
        with self._lock:
            got = self._done.pop(path, None)
            if got is not None:
                self._taken = max(self._taken, k)
            elif k >= self._reached:
                self._skip.add(k)   # the reader decodes this one itself
                if k < self._reached + CAUGHT_UP_FILES:
                    self._caught_up += 1
                    if self._caught_up >= CAUGHT_UP_TIMES:
                        self._stopped.set()
            self._drop_passed()
        if got is None:
            return None
        stamp, declared, pixels = got
        return (declared, pixels) if _stamp(path) == stamp else None

    def _drop_passed(self) -> None:
        """Once nothing more comes, drop what lies well behind the furthest file taken
        (under the lock)."""
        if self._stopped.is_set():
            for old in [p for p in self._done if self._position[p] < self._taken - KEPT_BEHIND]:
                del self._done[old]

    def _decode_all(self) -> None:
        try:
            self._decode_in_order()
        finally:
            self._stopped.set()
            with self._lock:
                self._drop_passed()

    def _decode_in_order(self) -> None:
        from pipestitch.io.images import MAX_PIXELS, decoded_bytes_bound, image_header

        spent, size = 0, None
        for k, path in enumerate(self._paths):
            if self._stopped.is_set():
                return
            with self._lock:
                if k in self._skip:
                    self._reached = k + 1
                    continue
            pixels, stamp = None, _stamp(path)
            try:
                data = file_bytes(path) if stamp is not None else np.empty(0, np.uint8)
                declared = image_header(data)
                # only what read_image would decode: a known header within its limit,
                # of the run's frame size
                ok = (declared is not None and declared[0] * declared[1] <= MAX_PIXELS
                      and declared == (size or declared))
                if ok:
                    size = declared
                    if spent + decoded_bytes_bound(data, declared) > self._budget:
                        return
                    pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
            except Exception:   # read_image meets the problem and reports it
                pixels = None
            with self._lock:
                self._reached = k + 1
                if (pixels is not None and not self._stopped.is_set()
                        and k not in self._skip):
                    self._done[path] = (stamp, declared, pixels)
                    spent += pixels.nbytes


_registry_lock = threading.Lock()
_active: DecodeAhead | None = None


def take(path: Path) -> tuple[tuple[int, int], np.ndarray] | None:
    """A file's pixels from the list being decoded ahead.

    Parameters
    ----------
    path : pathlib.Path
        The file.

    Returns
    -------
    tuple or None
        See :meth:`DecodeAhead.take`; None also when nothing is being decoded ahead.
    """
    ahead = _active
    return ahead.take(path) if ahead is not None else None
