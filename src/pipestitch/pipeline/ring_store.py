"""The ring points of a long run, kept in a temporary file instead of in memory.

After a frame's pose is fitted its ring inliers (:class:`pipestitch.pose.fit.RingPoints`,
<= 720 points) are read again only by the section refits after each round of pose
refinement (``pipeline.mosaic``). Kept in memory they are ~6 kB a frame for the whole
run, allocated among the pose pass's frame buffers: at 4000 pairs 23 MB of live data
and more of heap that cannot be handed back around them. :class:`RingStore` appends
each frame's in-plane points (float32) to an unlinked temporary file and hands back a
:class:`StoredRing`, a handle of a few dozen bytes that reads them when asked. What
the file holds sits in the page cache, which the system may drop, not in the
process's resident memory (where the temporary folder is a tmpfs, they are shared
memory: not in the resident size either, but not droppable). When no temporary file
can be made or written (no writable folder, a full disk), the store keeps the points
in memory from then on, as before, and says so once in ``problem``: the run goes on.
A handle reads through its open store: it cannot be pickled to another process.
"""

from __future__ import annotations

import tempfile
import threading
from dataclasses import dataclass
from types import TracebackType
from typing import BinaryIO

import numpy as np

from pipestitch.pose.fit import LaserPlane, RingPoints

__all__ = ["RingStore", "StoredRing"]

_POINT = np.dtype("<f4")   # uv components are float32, as RingPoints holds them


class RingStore:
    """Append-only store of ring points in an unlinked temporary file.

    Thread-safe: one lock serialises the file position for writes, reads and closing.
    Use as a context manager (or call :meth:`close`); the file disappears when it is
    closed. ``problem`` is "" unless the file failed and the points stay in memory.

    Parameters
    ----------
    directory : str, optional
        Where the temporary file is made (default: the system's temporary folder).
    """

    def __init__(self, directory: str | None = None) -> None:
        self._lock = threading.Lock()
        self._end = 0
        self._closed = False
        self.problem = ""
        try:
            self._file: BinaryIO | None = tempfile.TemporaryFile(dir=directory)
        except OSError as exc:
            self._file = None
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        self.problem = (f"ring points kept in memory: no temporary file ({exc}); "
                        "set TMPDIR to a writable folder for long runs")

    def put(self, ring: RingPoints | None) -> StoredRing | RingPoints | None:
        """Store a frame's in-plane points (its image pixels are not kept).

        Returns the handle, or the points themselves (without pixels) in memory when
        the file is unusable (``problem``).
        """
        if ring is None:
            return None
        data = np.ascontiguousarray(ring.uv, dtype=_POINT).tobytes()
        with self._lock:
            if self._file is not None and not self.problem:
                offset = self._end
                try:
                    self._file.seek(offset)
                    self._file.write(data)
                    self._file.flush()   # a full disk shows here, not at a later read
                except OSError as exc:   # earlier handles stay readable
                    self._fail(exc)
                else:
                    self._end += len(data)
                    return StoredRing(self, offset, len(data) // (2 * _POINT.itemsize),
                                      ring.plane, ring.noise_mm)
        return ring.without_pixels()

    def read(self, offset: int, n_points: int) -> np.ndarray:
        """The (n_points, 2) float32 uv stored at ``offset``.

        Raises
        ------
        RuntimeError
            When the store is closed.
        """
        size = n_points * 2 * _POINT.itemsize
        with self._lock:
            if self._closed or self._file is None:
                raise RuntimeError("ring store: read after the store was closed")
            self._file.seek(offset)
            data = self._file.read(size)
        if len(data) != size:
            raise OSError(f"ring store: expected {size} bytes at {offset}, read {len(data)}")
        return np.frombuffer(data, dtype=_POINT).reshape(n_points, 2)

    @property
    def nbytes(self) -> int:
        """Bytes stored so far."""
        return self._end

    def close(self) -> None:
        """Close (and so delete) the file; handles can no longer be read."""
        with self._lock:
            self._closed = True
            if self._file is not None:
                self._file.close()

    def __enter__(self) -> RingStore:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()


@dataclass(frozen=True, slots=True)
class StoredRing:
    """A frame's ring points in a :class:`RingStore`: what the section refits read of
    :class:`pipestitch.pose.fit.RingPoints` (``uv``, ``points_mm``, ``plane``), read
    from the file on each access. ``pixels`` is empty: the image points are not kept.
    """

    store: RingStore
    offset: int
    n_points: int
    plane: LaserPlane
    noise_mm: float = 0.05   # the point noise of the frame's fit (RingPoints.noise_mm)

    @property
    def uv(self) -> np.ndarray:
        """(N, 2) in-plane coordinates, mm (float32, read-only)."""
        return self.store.read(self.offset, self.n_points)

    @property
    def pixels(self) -> np.ndarray:
        """Not kept: an empty (0, 2) array."""
        return np.empty((0, 2), np.float32)

    @property
    def points_mm(self) -> np.ndarray:
        """(N, 3) probe-frame points on the laser plane (float64)."""
        return self.plane.to_probe(self.uv.astype(np.float64))
