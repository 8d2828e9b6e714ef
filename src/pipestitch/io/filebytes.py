"""A whole file as a uint8 array, read with the GIL released.

A raw file object's ``readinto`` releases the GIL around the system call, into an
array made for the file's size. ``numpy.fromfile`` was seen holding it during frame
reads (``py-spy --gil`` on a 250-pair run: 2.7 % of the GIL-holding samples on its
line, 0.5 % on these), time in which the run's other threads could not run Python.
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
