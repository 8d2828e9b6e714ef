"""The run's heap policy: per-frame buffers are reused from the heap, not mapped anew."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from pipestitch._runtime.memory import every_n

# Allocates and frees a 20 MB buffer (a full-size frame as float32) 20 times after a
# first one, and prints the page faults those 20 cost.
PROBE = """
import resource, sys
import numpy as np
from pipestitch._runtime.memory import keep_buffers_in_heap
if sys.argv[1] == "heap":
    assert keep_buffers_in_heap() and keep_buffers_in_heap()
faults = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_minflt
buf = np.ones(5_000_000, np.float32); del buf
start = faults()
for _ in range(20):
    buf = np.ones(5_000_000, np.float32); del buf
print(faults() - start)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True,
                         check=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(platform.system() != "Linux" or not platform.libc_ver()[0] == "glibc",
                    reason="glibc's allocator only")
def test_frame_sized_buffers_are_reused_from_the_heap() -> None:
    # glibc maps such a buffer anew each time, so its pages fault in again (5 000 4-kB
    # pages, or 10 huge pages: at least one fault per buffer); held in the heap, the
    # same pages are reused.
    assert _faults("heap") <= 2
    assert _faults("mapped") >= 20


def test_every_n_calls_after_each_nth_item() -> None:
    calls: list[int] = []
    items = list(every_n(range(7), 3, lambda: calls.append(1)))
    assert items == list(range(7)) and len(calls) == 2
    with pytest.raises(ValueError):
        list(every_n(range(3), 0, lambda: None))
