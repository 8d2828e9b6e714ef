"""Handing freed heap memory back to the system during a run.

Each pass of ``pipestitch run`` allocates and frees hundreds of MB of strips, spectra
and patches on several threads, between which small per-frame results stay alive for
the whole run. glibc serves a freed large block's size from its heap afterwards (its
mmap threshold rises up to 32 MB), so the large buffers come to share heap pages with
those small results, and the heap grows with the run. :func:`map_large_blocks` keeps
the threshold at glibc's default of 128 kB (large buffers are mapped and unmapped,
never left in the heap); :func:`release_free_memory` (``malloc_trim(0)``) returns the
free pages of every arena between passes. Elsewhere (another C library) both are
no-ops.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

__all__ = ["MMAP_THRESHOLD_BYTES", "map_large_blocks", "release_free_memory"]

MMAP_THRESHOLD_BYTES = 128 * 1024
_M_MMAP_THRESHOLD = -3          # mallopt parameter (glibc malloc.h)


@functools.cache
def _libc_function(name: str) -> ctypes._CFuncPtr | None:
    path = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(path) if path else None
    except OSError:
        return None
    return getattr(libc, name, None) if libc is not None else None


def map_large_blocks(threshold: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Serve every heap block of at least ``threshold`` bytes by its own mapping.

    glibc ``mallopt(M_MMAP_THRESHOLD, threshold)``, which also stops glibc raising the
    threshold as large blocks are freed. Process-wide; measured on a 150-pair run:
    peak 623 MB instead of 710, the same time.

    Returns
    -------
    bool
        True when set; False where the C library has no ``mallopt``.
    """
    mallopt = _libc_function("mallopt")
    return bool(mallopt(_M_MMAP_THRESHOLD, int(threshold))) if mallopt is not None else False


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
