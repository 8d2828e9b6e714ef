"""The run's heap policy: per-frame buffers are reused from the heap, not mapped anew."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from pipestitch._runtime.memory import every_n

# Holds five 20 MB buffers (full-size frames as float32) at once and frees them, five
# times after a first round, on the main thread or on a worker thread as the run's
# passes do, and prints the page faults those five rounds cost.
PROBE = """
import resource, sys, threading
import numpy as np
from pipestitch._runtime.memory import keep_buffers_in_heap
if sys.argv[1] == "heap":
    assert keep_buffers_in_heap() and keep_buffers_in_heap()
faults = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_minflt
def cycle():
    buffers = [np.ones(5_000_000, np.float32) for _ in range(5)]
    del buffers
def rounds():
    cycle()
    start = faults()
    for _ in range(5):
        cycle()
    print(faults() - start)
if sys.argv[2] == "worker":
    worker = threading.Thread(target=rounds)
    worker.start()
    worker.join()
else:
    rounds()
"""


def _faults(mode: str, thread: str = "main") -> int:
    # glibc's own allocator settings out of the child's environment: dask's LocalCluster
    # leaves MALLOC_TRIM_THRESHOLD_ in this process's environment after a batch test.
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    out = subprocess.run([sys.executable, "-c", PROBE, mode, thread], capture_output=True,
                         text=True, check=True, env=env)
    return int(out.stdout.strip())


@pytest.mark.skipif(platform.system() != "Linux" or not platform.libc_ver()[0] == "glibc",
                    reason="glibc's allocator only")
def test_frame_sized_buffers_are_reused_from_the_heap() -> None:
    # By default glibc hands the freed top of its heap back to the system (its trim
    # threshold) and the next round faults the pages in again (10 940 faults measured);
    # held in the heap, the same pages are reused.
    assert _faults("heap") <= 2
    assert _faults("mapped") >= 100
    # A worker thread's own arena deletes its heap when it empties (5 395 faults
    # measured with the thresholds alone); from the main arena, reused.
    assert _faults("heap", "worker") <= 2
    assert _faults("mapped", "worker") >= 100


# numpy's huge-page mark of its large buffers, after the run's heap policy is made
HINT = """
try:
    from numpy._core.multiarray import _get_madvise_hugepage
except ImportError:   # numpy 1.26
    from numpy.core.multiarray import _get_madvise_hugepage
from pipestitch._runtime.memory import keep_buffers_in_heap
keep_buffers_in_heap()
print(_get_madvise_hugepage())
"""


@pytest.mark.parametrize(("chosen", "expected"), [(None, "False"), ("1", "True"),
                                                  ("0", "False")])
def test_the_heap_policy_turns_numpys_huge_page_mark_off_unless_the_user_chose(
        chosen: str | None, expected: str) -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if chosen is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = chosen
    out = subprocess.run([sys.executable, "-c", HINT], capture_output=True, text=True,
                         check=True, env=env)
    assert out.stdout.strip() == expected


def test_every_n_calls_after_each_nth_item() -> None:
    calls: list[int] = []
    items = list(every_n(range(7), 3, lambda: calls.append(1)))
    assert items == list(range(7)) and len(calls) == 2
    with pytest.raises(ValueError):
        list(every_n(range(3), 0, lambda: None))


def test_the_heap_policy_leaves_each_setting_the_user_made_alone(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from pipestitch._runtime import memory

    calls: list[int] = []

    def mallopt(param: int, value: int) -> int:
        calls.append(param)
        return 1

    thresholds, arena = [-3, -1], [-8]   # glibc's M_MMAP_THRESHOLD, M_TRIM_THRESHOLD, M_ARENA_MAX
    cases = ((None, {}, False, []),
             (mallopt, {}, True, thresholds + arena),
             (mallopt, {"MALLOC_TRIM_THRESHOLD_": "1"}, True, arena),
             (mallopt, {"MALLOC_ARENA_MAX": "4"}, True, thresholds),
             (mallopt, {"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}, True, thresholds),
             (mallopt, {"MALLOC_MMAP_THRESHOLD_": "1", "MALLOC_ARENA_MAX": "2"}, False, []))
    try:
        for libc, env, expected, params in cases:
            memory.keep_buffers_in_heap.cache_clear()
            calls.clear()
            monkeypatch.setattr(memory, "_libc_function", lambda name, f=libc: f)
            for key in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX",
                        "GLIBC_TUNABLES"):
                monkeypatch.delenv(key, raising=False)
            for key, value in env.items():
                monkeypatch.setenv(key, value)
            assert memory.keep_buffers_in_heap() is expected, env
            assert calls == params, env
    finally:
        memory.keep_buffers_in_heap.cache_clear()
