"""Image files decoded ahead on one thread, for a reader that comes later.

:class:`DecodeAhead` decodes a list of files in order while the caller does something
else that leaves a core free (a command importing its stages); OpenCV releases the GIL
while it decodes, so the two overlap. :func:`pipestitch.io.images.read_image` then takes
a file's pixels from here (:func:`take`) instead of decoding it again, after the same
checks it makes on a file it decodes itself, so what it returns, and every error it
raises, is the same either way. Only one list is decoded ahead at a time.

A file is taken only when its size and modification time are still those it had when it
was decoded. The thread stops at the end of the list, at ``budget_bytes`` of decoded
pixels, when the reader has asked twice for the file it is decoding or one of the next few
(the reader has caught up: from there on decoding ahead would only duplicate its work), or
at :meth:`stop`; it never decodes a file the reader has already asked for. Once it has
stopped, files well behind the reader are dropped, and all at :meth:`stop`, so nothing
decoded ahead outlives its use.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

import cv2
import numpy as np

__all__ = ["DecodeAhead", "take"]

# The reader has caught up when it has asked this many times for a file this close ahead
# of the thread (once could be a reader on another thread sampling the run); once the
# thread has stopped, files this far behind a request are dropped (readers on a few
# threads ask slightly out of order).
CAUGHT_UP_FILES = 4
CAUGHT_UP_TIMES = 2
KEPT_BEHIND = 16


def _stamp(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


class DecodeAhead:
    """Decode ``paths`` in order on one thread (a context manager: started on entry,
    stopped and joined on exit).

    Parameters
    ----------
    paths : sequence of pathlib.Path
        The files, in the order the reader will ask for them.
    budget_bytes : int
        Most bytes of decoded pixels to produce.
    """

    def __init__(self, paths: Sequence[Path], budget_bytes: int) -> None:
        self._paths = [Path(p) for p in paths]
        self._position = {p: k for k, p in enumerate(self._paths)}
        self._budget = budget_bytes
        self._done: dict[Path, tuple[tuple[int, int], tuple[int, int], np.ndarray]] = {}
        self._reached = 0           # files before this one were decoded or passed over
        self._skip: set[int] = set()   # asked for before the thread reached them
        self._caught_up = 0
        self._stopped = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._decode_all, name="decode-ahead",
                                        daemon=True)

    def __enter__(self) -> DecodeAhead:
        global _active
        with _registry_lock:
            _active = self
        self._thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def stop(self) -> None:
        """Stop decoding, wait for the thread, release what was not taken."""
        global _active
        self._stopped.set()
        if self._thread.is_alive():
            self._thread.join()
        with _registry_lock:
            if _active is self:
                _active = None
        with self._lock:
            self._done.clear()

    @property
    def decoded(self) -> int:
        """Files decoded and not yet taken or dropped."""
        with self._lock:
            return len(self._done)

    def take(self, path: Path) -> tuple[tuple[int, int], np.ndarray] | None:
        """(declared width and height, pixels) of ``path`` if it was decoded ahead and is
        unchanged since; None otherwise (the caller reads the file itself)."""
        k = self._position.get(path)
        if k is None:
            return None
        with self._lock:
            got = self._done.pop(path, None)
            if got is None and k >= self._reached:
                self._skip.add(k)   # the reader decodes this one itself
                if k < self._reached + CAUGHT_UP_FILES:
                    self._caught_up += 1
                    if self._caught_up >= CAUGHT_UP_TIMES:
                        self._stopped.set()
            if self._stopped.is_set():   # nothing comes after: drop what was passed over
                for old in [p for p in self._done if self._position[p] < k - KEPT_BEHIND]:
                    del self._done[old]
        if got is None:
            return None
        stamp, declared, pixels = got
        return (declared, pixels) if _stamp(path) == stamp else None

    def _decode_all(self) -> None:
        from pipestitch.io.images import MAX_PIXELS, image_header

        spent = 0
        for k, path in enumerate(self._paths):
            if self._stopped.is_set() or spent >= self._budget:
                return
            with self._lock:
                if k in self._skip:
                    self._reached = k + 1
                    continue
            try:
                stamp = _stamp(path)
                data = np.fromfile(path, dtype=np.uint8)
                declared = image_header(data)
                # only what read_image would decode: a known header within its limit
                ok = declared is not None and declared[0] * declared[1] <= MAX_PIXELS
                pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if ok else None
            except (OSError, ValueError, cv2.error):
                pixels = None   # read_image meets the problem and reports it
            with self._lock:
                self._reached = k + 1
                if pixels is not None and stamp is not None and not self._stopped.is_set():
                    self._done[path] = (stamp, declared, pixels)
                    spent += pixels.nbytes


_registry_lock = threading.Lock()
_active: DecodeAhead | None = None


def take(path: Path) -> tuple[tuple[int, int], np.ndarray] | None:
    """``path``'s pixels from the list being decoded ahead (see :meth:`DecodeAhead.take`);
    None when nothing is decoded ahead or not this file."""
    ahead = _active
    return ahead.take(path) if ahead is not None else None
