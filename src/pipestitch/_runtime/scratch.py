"""Frame-sized scratch arrays, one set per thread, reused from frame to frame.

A run converts every frame to float32 several times (the laser ring, the LED frame's
reflectance, each unwrapping pass): 5-20 MB a time. Freshly allocated, each such
array is mapped and faulted in page by page, and the run hands free memory back to
the system between frames (:mod:`pipestitch._runtime.memory`), so most of them are:
at full size that kernel work was ~10 % of a run. Temporaries that do not outlive
the call that makes them take a buffer from here instead: the same memory is reused
by the next frame the thread works on. A thread's buffers go with the thread (the
run's worker pools end with each pass); :func:`release` drops the calling thread's.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["buffer", "release"]

_local = threading.local()


def buffer(key: str, shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
    """This thread's array for ``key`` (contents undefined), made anew when the shape or
    dtype differ from the last request.

    The caller must be done with it before it asks for ``key`` again on this thread:
    never return it, or anything viewing it, to code that keeps it.
    """
    arrays: dict[str, np.ndarray] = _local.__dict__.setdefault("arrays", {})
    arr = arrays.get(key)
    if arr is None or arr.shape != tuple(shape) or arr.dtype != np.dtype(dtype):
        arrays[key] = arr = np.empty(shape, dtype)
    return arr


def release() -> None:
    """Drop the calling thread's buffers."""
    _local.__dict__.pop("arrays", None)
