"""A whole file as a uint8 array, read with the GIL released.

``numpy.fromfile`` holds the GIL through the read itself: a worker thread reading a
frame file stops the other threads' Python for as long as the read takes (measured:
a Python thread beside a loop of ``fromfile`` reads of frame files ran at half its
speed, beside the same reads through a file object's ``readinto`` at 91 %). A raw
file object's ``readinto`` releases it around the system call, so the frame files of
a run are read this way.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["file_bytes"]


def file_bytes(path: str | Path) -> np.ndarray:
    """The bytes of ``path`` as a 1-D uint8 array (what ``numpy.fromfile(path, uint8)``
    gives).

    Raises
    ------
    OSError
        If the file cannot be opened or read (``FileNotFoundError`` when missing).
    """
    with open(path, "rb", buffering=0) as fh:
        data = np.empty(os.fstat(fh.fileno()).st_size, np.uint8)
        view, got = memoryview(data), 0
        while got < data.size:
            n = fh.readinto(view[got:])
            if not n:   # the file shrank while it was read
                break
            got += n
        if got == data.size:   # read on past the size: a file that grew meanwhile
            more = fh.read()
            if more:
                return np.concatenate([data, np.frombuffer(more, np.uint8)])
    return data[:got]
