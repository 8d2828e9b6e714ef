"""A bounded cache of decoded LED frames shared by the stages of one run.

``pipestitch run`` reads each LED frame in the pose stage (ring reflectance,
photometric evidence), for the occluder mask, in every registration round and
for the stitch: four or five PNG decodes of the same file. Decoding is a tenth of
the run's time, so the frames are kept when the whole run's LED frames fit in a
memory budget. A longer run is read in full passes, which an LRU cache of part of it
would never hit: it is not cached at all, so its memory does not grow with its length.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any

import numpy as np

__all__ = ["CachedLedFrames"]

DEFAULT_BUDGET_BYTES = 512 * 2**20


class CachedLedFrames:
    """A dataset whose ``read_led`` keeps decoded frames when the run fits ``budget_bytes``.

    Whether it fits is judged from the first frame read (all frames of a run have one
    size). Every other attribute is the wrapped dataset's. Thread-safe; frames are
    returned read-only (callers convert them, never write into them).
    """

    def __init__(self, dataset: Any, budget_bytes: int = DEFAULT_BUDGET_BYTES) -> None:
        self._dataset = dataset
        self._budget = budget_bytes
        self._frames: OrderedDict[int, np.ndarray] = OrderedDict()
        self._bytes = 0
        self._enabled: bool | None = None   # decided on the first frame read
        self._lock = threading.Lock()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._dataset, name)

    def read_led(self, index: int) -> np.ndarray:
        """LED frame ``index`` as stored (raises what the dataset raises)."""
        with self._lock:
            frame = self._frames.get(index)
            if frame is not None:
                self._frames.move_to_end(index)
                return frame
        frame = self._dataset.read_led(index)
        frame.flags.writeable = False
        with self._lock:
            if self._enabled is None:
                self._enabled = frame.nbytes * self._dataset.n_pairs <= self._budget
            if self._enabled and index not in self._frames:
                self._frames[index] = frame
                self._bytes += frame.nbytes
                while self._bytes > self._budget:   # a frame of another size: stay bounded
                    _, old = self._frames.popitem(last=False)
                    self._bytes -= old.nbytes
        return frame
