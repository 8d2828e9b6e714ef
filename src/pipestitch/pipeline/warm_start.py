"""What a command does while it is still starting: decode the run's first frames.

``pipestitch run`` spends its first ~0.6 s importing its stages (numba, scipy, the
configuration models) on one core of a 2-core machine; the other core is idle. Started
before those imports, :func:`decode_ahead` decodes the dataset's frames in the order the
pose pass reads them (laser, then LED, pair by pair) on that core; the pose pass then
takes them instead of decoding them (:mod:`pipestitch.io.ahead`: the same pixels and the
same checks). Measured on 60 pairs at 1224 x 1024: ~40 frames are decoded by the time
the imports end, which slow down by ~0.03 s (docs/benchmarks.md).
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path

from pipestitch._runtime.memory import keep_buffers_in_heap
from pipestitch.io.ahead import DecodeAhead
from pipestitch.io.frame_files import frame_files

__all__ = ["DECODE_AHEAD_BYTES", "decode_ahead", "loading_stages"]

# Decoded pixels the thread may produce: about what it decodes while the command starts
# (~40 frames of 1224 x 1024 at 8 bits). They are held until the pose pass takes them, at
# the start of the run, where its memory peaks: a larger budget kept the thread decoding
# beside the pose pass (no faster: both cores are busy there) and raised that peak.
DECODE_AHEAD_BYTES = 48 * 2**20


def decode_ahead(dataset: str | Path, *, video: Path | None = None
                 ) -> AbstractContextManager[DecodeAhead | None]:
    """Decode ``dataset``'s first frames on a thread for the ``with`` block's pose pass.

    Makes the run's allocator settings
    (:func:`pipestitch._runtime.memory.keep_buffers_in_heap`) first.

    Parameters
    ----------
    dataset : str or pathlib.Path
        The dataset folder (SPEC layout).
    video : pathlib.Path, optional
        The run's video, when its frames come from one: nothing is decoded ahead.

    Returns
    -------
    contextlib.AbstractContextManager
        The :class:`pipestitch.io.ahead.DecodeAhead` to enter; a context doing nothing
        (entered as None) for a video or a dataset without a readable frames/ folder:
        the run then meets and reports what is wrong, as it would without this.
    """
    frames_dir = Path(dataset) / "frames"
    if video is not None:
        return nullcontext()
    try:
        found, _ = frame_files(frames_dir)
    except OSError:
        return nullcontext()
    lasers, leds = found["laser"], found["led"]
    order = [p for i in sorted(lasers) for p in (lasers[i], leds.get(i)) if p is not None]
    # the run's allocator settings, before the thread's first allocation: otherwise the
    # thread gets an arena of its own, which a worker of the run inherits when it ends
    # (measured: +170 MB peak at 2448 x 2048)
    keep_buffers_in_heap()
    return DecodeAhead(order, DECODE_AHEAD_BYTES)


@contextmanager
def loading_stages() -> Iterator[None]:
    """The ``with`` block imports a command's stages: Python's cyclic garbage collector
    is held off while it does, and what the block made is kept out of later collections.

    Importing the stages makes some hundred thousand objects (modules, classes,
    functions, numba's and scipy's tables), none of them garbage, and the collector,
    started every 700 allocations, traverses the growing heap again and again: 0.1-0.2 s
    of the command's start (measured on `import pipestitch.pipeline.run`: 0.83-1.02 s
    against 0.66-0.79 s without). They live as long as the process, so afterwards
    ``gc.freeze`` moves every object alive into the permanent generation, which
    collections skip. The collector is enabled again as it was, also when the block
    fails.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()
    gc.freeze()

