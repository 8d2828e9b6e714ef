"""Handing freed heap memory back to the system during a run.

Each pass of ``pipestitch run`` allocates and frees hundreds of MB of strips, spectra
and patches on several threads, between which small per-frame results stay alive for
the whole run. :func:`release_free_memory` (``malloc_trim(0)``) returns the free
pages of every arena between passes, so each pass starts from what is live, and every
``TRIM_EVERY`` frames within a pass (``pipestitch._runtime.threads.ordered_map``), so a pass's
free-but-resident heap does not grow with its length. (Holding
glibc's mmap threshold at 128 kB, so that large buffers are always mapped, took a
further ~0.05 MB a pair off the resident size but made runs ~30 % slower: every
strip-sized buffer then costs a mapping and its page faults; not done.) Elsewhere
(another C library) it is a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

__all__ = ["TRIM_EVERY", "every_n", "release_free_memory"]

T = TypeVar("T")
# Frames between two hand-backs within a pass: a trim costs a few ms and the page
# faults of re-touching what it returned, against ~0.07 MB a frame of free heap the
# resident size otherwise gains through a pass (measured at 1000 pairs).
TRIM_EVERY = 50


@functools.cache
def _libc_function(name: str) -> ctypes._CFuncPtr | None:
    path = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(path) if path else None
    except OSError:
        return None
    return getattr(libc, name, None) if libc is not None else None


def every_n(items: Iterable[T], n: int, action: Callable[[], object]) -> Iterator[T]:
    """The items, calling ``action()`` after every ``n``-th.

    ``action`` runs when the item after the ``n``-th is asked for (a generator cannot
    run code between handing an item out and being resumed), so not at all when the
    consumer stops right after an ``n``-th item.

    Parameters
    ----------
    items : iterable
        What to pass through.
    n : int
        Items between two calls (>= 1).
    action : callable
        Called without arguments.
    """
    if n < 1:
        raise ValueError(f"every_n: n must be >= 1, got {n}")
    for k, item in enumerate(items, start=1):
        yield item
        if k % n == 0:
            action()


def release_free_memory() -> bool:
    """Give the heap's free pages back to the system (glibc ``malloc_trim(0)``).

    Returns
    -------
    bool
        True when memory was released; False when none could be or the C library
        has no ``malloc_trim``.
    """
    trim = _libc_function("malloc_trim")
    return bool(trim(0)) if trim is not None else False
