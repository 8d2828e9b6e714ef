"""Atomic outputs' permissions when several threads write at once."""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import pytest

from pipestitch.io import atomic


@pytest.mark.skipif(os.name != "posix", reason="file modes and the umask are POSIX's")
def test_threads_reading_the_umask_at_once_keep_it(tmp_path: Path) -> None:
    """The umask is read by setting it for a moment: threads doing that at once,
    unguarded, read 0 (files made 0666) and can leave the process's umask at 0, so
    that every later file and folder is open to all. A run writes its outputs from
    several threads at once; each file still gets 0666 minus the umask."""
    old = os.umask(0o027)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)   # threads take turns as often as they can
    read: set[int] = set()
    try:
        def reads() -> None:
            read.update(atomic._umask() for _ in range(5000))

        threads = [threading.Thread(target=reads) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert read == {0o027}
        assert os.umask(0o027) == 0o027
        out = atomic.atomic_write_bytes(tmp_path / "a.bin", b"x")
        assert out.stat().st_mode & 0o777 == 0o640
    finally:
        sys.setswitchinterval(switch)
        os.umask(old)
