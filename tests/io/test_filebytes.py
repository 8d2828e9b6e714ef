"""Whole files read as numpy bytes (the frames' reader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipestitch.io.filebytes import file_bytes


@pytest.mark.parametrize("size", [0, 1, 4095, 4096, 3_000_001])
def test_file_bytes_are_numpys_fromfile(tmp_path: Path, size: int) -> None:
    path = tmp_path / "frame.png"
    path.write_bytes(np.random.default_rng(size).integers(0, 256, size, np.uint8).tobytes())
    got = file_bytes(path)
    want = np.fromfile(path, np.uint8)
    assert got.dtype == np.uint8 and got.ndim == 1 and got.flags.writeable
    np.testing.assert_array_equal(got, want)


def test_a_missing_file_is_an_os_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        file_bytes(tmp_path / "missing.png")
