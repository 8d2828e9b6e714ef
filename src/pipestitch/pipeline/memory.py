"""Handing freed heap memory back to the system between the passes of a run.

Each pass of ``pipestitch run`` allocates and frees hundreds of MB of strips, spectra
and patches on several threads. glibc keeps what was freed in its arenas (one per
thread), so a pass that follows one with a higher peak can start from that peak's
resident size instead of from what is live. ``malloc_trim(0)`` releases the free
pages of every arena; elsewhere (another C library) this is a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

__all__ = ["release_free_memory"]


@functools.cache
def _malloc_trim() -> ctypes._CFuncPtr | None:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return getattr(libc, "malloc_trim", None) if libc is not None else None


def release_free_memory() -> bool:
    """Give the heap's free pages back to the system (glibc ``malloc_trim(0)``).

    Returns
    -------
    bool
        True when memory was released; False when none could be or the C library
        has no ``malloc_trim``.
    """
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False
