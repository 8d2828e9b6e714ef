"""Handing freed heap memory back to the system during a run.

Each pass of ``pipestitch run`` allocates and frees hundreds of MB of strips, spectra
and patches on several threads, between which small per-frame results stay alive for
the whole run. :func:`release_free_memory` (``malloc_trim(0)``) returns the free
pages of every arena between passes, so each pass starts from what is live, and every
``TRIM_EVERY`` frames within a pass (``pipestitch._runtime.threads.ordered_map``), so a pass's
free-but-resident heap does not grow with its length. (Holding
glibc's mmap threshold at 128 kB, so that large buffers are always mapped, took a
further ~0.05 MB a pair off the resident size but made runs ~30 % slower: every
strip-sized buffer then costs a mapping and its page faults; not done.) The opposite,
:func:`keep_buffers_in_heap`, is done: buffers up to ``HEAP_BUFFER_MB`` (a full-size
frame as float32 is 20 MB) come from the heap and are reused after they are freed,
instead of being mapped, zeroed by the kernel and unmapped each time, and freeing
does not trim the heap by itself (the trims above do, at known points); and every
thread allocates from the one main heap (glibc's ``M_ARENA_MAX`` = 1): a worker thread's
own arena grows in heaps of at most 64 MB that glibc deletes as soon as they are empty,
so a frame-sized buffer there was mapped and zeroed afresh for nearly every frame (936
heaps made and deleted in a 60-pair full-size run). Elsewhere (another C library) all
of this is a no-op.

numpy marks each buffer of 4 MB or more for transparent huge pages (``madvise``
``MADV_HUGEPAGE``), and the mark stays on those pages of the heap after the buffer is
freed (numpy issue 31590): where the system gives huge pages only to marked memory
(``/sys/kernel/mm/transparent_hugepage/enabled`` ``madvise``, as on the machine of
docs/benchmarks.md), each first touch of a marked page after a trim had the kernel zero
2 MB at once, whatever part of it was used. :func:`without_huge_page_hints` turns the
mark off for the run (:func:`keep_buffers_in_heap` calls it): on a 60-pair half-size run
177-212 huge pages faulted in and the kernel's page zeroing 2.0 % of the CPU samples
against 0.27 %, system time 0.8-1.4 s against 0.7-0.8 s; runs of 60 pairs 2-5 % faster
at either frame size, 1000 pairs in the same time.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import importlib
import os
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

__all__ = ["HEAP_BUFFER_MB", "TRIM_EVERY", "every_n", "keep_buffers_in_heap",
           "release_free_memory", "without_huge_page_hints"]

T = TypeVar("T")
# Frames between two hand-backs within a pass: a trim costs a few ms and the page
# faults of re-touching what it returned (the kernel zeroes each page again), against
# ~0.07 MB a frame of free heap the resident size otherwise gains through a pass
# (measured at 1000 pairs). Every 50 frames: 0.86-0.90 M page faults at 1000 pairs,
# 95-97 s of CPU; every 250: 0.28-0.30 M, 89 s, the peak ~15 MB higher and as flat in
# the run's length (docs/benchmarks.md).
TRIM_EVERY = 250
# Buffers up to this size are served from the heap (glibc's mmap threshold; 32 MB is the
# most its own adaptive threshold reaches on 64-bit systems), which is trimmed only by
# release_free_memory (glibc's trim threshold set far above any run).
HEAP_BUFFER_MB = 32
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8   # glibc's mallopt parameters


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


@functools.cache
def keep_buffers_in_heap() -> bool:
    """Serve buffers up to ``HEAP_BUFFER_MB`` from one heap, trimmed only on request.

    glibc maps every buffer above its (adaptive) mmap threshold separately: each of a
    run's per-frame strips, spectra and frames then costs a mapping, the kernel's
    zeroing of its pages and an unmapping: on a 60-pair half-size run, 370 000 page
    faults and ~3 s of system time of its ~13 s of CPU time, against 175 000 faults
    held in the heap. The worker threads' own arenas would do the same in heaps glibc
    deletes when they empty, so threads allocate from the main arena (at full size:
    350 000 faults and 6-8 s of system time against 200 000 and 4-5 s, peak ~100 MB
    lower). Process-wide and idempotent. The arena limit holds for threads that have
    not allocated before it (glibc gives a new thread an arena an exited one left
    free, and shares the existing arenas once there are more than the limit), so it
    is set before a run starts its threads. The heap's free pages are still handed
    back by :func:`release_free_memory` between passes and every ``TRIM_EVERY`` frames.
    numpy's huge-page mark is turned off first (:func:`without_huge_page_hints`).

    Each setting the user gave glibc is left as it is: the thresholds when
    ``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_TRIM_THRESHOLD_`` (or their ``GLIBC_TUNABLES``)
    are set, the arenas when ``MALLOC_ARENA_MAX`` (or ``glibc.malloc.arena_max``) is.

    Returns
    -------
    bool
        True when the C library took every setting made here and at least one was
        made (glibc), False otherwise (on a C library that refused the mmap threshold,
        nothing more was set).
    """
    without_huge_page_hints()
    mallopt = _libc_function("mallopt")
    if mallopt is None:
        return False
    thresholds_set, arenas_set = _user_allocator_settings()
    took = not (thresholds_set and arenas_set)
    if not thresholds_set:
        if not mallopt(_M_MMAP_THRESHOLD, HEAP_BUFFER_MB << 20):   # e.g. above 32-bit limits
            return False
        took = bool(mallopt(_M_TRIM_THRESHOLD, (1 << 31) - 1)) and took   # a C int: 2 GB
    if not arenas_set:
        took = bool(mallopt(_M_ARENA_MAX, 1)) and took
    return took


@functools.cache
def without_huge_page_hints() -> bool:
    """Stop numpy marking its large buffers for transparent huge pages (module docstring).

    Process-wide and idempotent; left alone where the user chose
    (``NUMPY_MADVISE_HUGEPAGE`` set, which numpy reads at its import).

    Returns
    -------
    bool
        True when the mark is off from now on; False where the user chose or this numpy
        has no such setting.
    """
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return False
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):   # numpy 2, 1.26
        try:
            setter = getattr(importlib.import_module(name), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if setter is not None:
            setter(False)
            return True
    return False


def _user_allocator_settings() -> tuple[bool, bool]:
    """Whether the environment sets glibc's mmap or trim threshold, and its arenas."""
    tunables = os.environ.get("GLIBC_TUNABLES", "")
    thresholds = (any(k in os.environ for k in ("MALLOC_MMAP_THRESHOLD_",
                                                "MALLOC_TRIM_THRESHOLD_"))
                  or any(f"glibc.malloc.{t}" in tunables
                         for t in ("mmap_threshold", "trim_threshold")))
    arenas = "MALLOC_ARENA_MAX" in os.environ or "glibc.malloc.arena_max" in tunables
    return thresholds, arenas
