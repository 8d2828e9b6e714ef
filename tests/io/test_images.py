"""Frames are measured before they are decoded: a file that declares a wrong size or a
huge one is refused from its header, so memory never follows what a file declares."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from pipestitch.errors import DatasetError
from pipestitch.io.images import MAX_PIXELS, decoded_bytes_bound, image_header, read_image


def bomb_png(path: Path, width: int, height: int, bit_depth: int = 8, colour: int = 0) -> Path:
    """A valid, tiny PNG that declares ``width`` x ``height``: an all-zero image compresses
    to almost nothing (a few hundred bytes for any size we try)."""
    raw_row = b"\x00" * (1 + width * (bit_depth // 8) * {0: 1, 2: 3}[colour])
    compressor = zlib.compressobj(9)
    body = b"".join(compressor.compress(raw_row) for _ in range(min(height, 64)))
    body += compressor.flush()   # truncated data: a decoder would fail late, after allocating

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body)
                     + chunk(b"IEND", b""))
    return path


def test_header_sizes_of_png_and_tiff(tmp_path: Path) -> None:
    img = np.zeros((30, 40), np.uint16)
    cv2.imwrite(str(tmp_path / "a.png"), img)
    tifffile.imwrite(tmp_path / "a.tif", img)
    for name in ("a.png", "a.tif"):
        assert image_header((tmp_path / name).read_bytes()) == (40, 30)
    assert image_header(b"\xff\xd8\xff\xe0 a jpeg") is None
    assert image_header(bomb_png(tmp_path / "b.png", 30000, 30000).read_bytes()) == (30000, 30000)


def test_a_frame_declaring_another_size_is_refused_undecoded(tmp_path: Path) -> None:
    path = bomb_png(tmp_path / "laser_00000.png", 18000, 18000, 16, 2)
    assert path.stat().st_size < 100_000
    declared = r"18000x18000, probe.toml says 1224x1024 \(from its header; not decoded\)"
    with pytest.raises(DatasetError, match=declared):
        read_image(path, size=(1224, 1024))


def test_a_huge_image_is_refused_whatever_the_caller_expects(tmp_path: Path) -> None:
    side = int(np.sqrt(MAX_PIXELS)) + 1
    with pytest.raises(DatasetError, match="more than"):
        read_image(bomb_png(tmp_path / "huge.png", side, side))


def test_an_image_the_decoder_refuses_is_a_dataset_error(tmp_path: Path) -> None:
    path = tmp_path / "x.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    with pytest.raises(DatasetError, match=r"x\.png"):
        read_image(path)


def test_a_bomb_frame_is_one_reported_skipped_frame_of_a_run(tmp_path: Path,
                                                             simulate_small) -> None:
    from typer.testing import CliRunner

    from pipestitch.cli.app import app

    data = simulate_small(tmp_path / "ds", "--pairs", "3", "--seed", "5")
    bomb_png(data / "frames" / "laser_00001.png", 30000, 30000)
    check = CliRunner().invoke(app, ["check", str(data)])
    assert check.exit_code == 2 and "laser_00001.png" in check.output
    result = CliRunner().invoke(app, ["run", str(data), "--out", str(tmp_path / "out"), "-q"])
    assert result.exit_code == 0, result.output
    assert "laser_00001.png" in result.output and "not decoded" in result.output
    poses = (tmp_path / "out" / "poses.csv").read_text().splitlines()
    assert len(poses) == 4 and "not decoded" in poses[2]


def test_header_of_a_planar_tiff_is_its_image_size(tmp_path: Path) -> None:
    img = np.zeros((3, 48, 64), np.uint8)   # samples first, as a planar TIFF stores them
    tifffile.imwrite(tmp_path / "planar.tif", img, planarconfig="separate", photometric="rgb")
    assert image_header((tmp_path / "planar.tif").read_bytes()) == (64, 48)
    assert read_image(tmp_path / "planar.tif", size=(64, 48)).shape[:2] == (48, 64)


def test_a_jpeg_declaring_a_huge_size_is_refused_from_its_header(tmp_path: Path) -> None:
    _, buf = cv2.imencode(".jpg", np.zeros((16, 16), np.uint8))
    data = bytearray(buf.tobytes())
    sof = data.index(b"\xff\xc0")             # baseline frame header: height, width at +5
    data[sof + 5:sof + 9] = struct.pack(">HH", 30000, 30000)
    (tmp_path / "bomb.jpg").write_bytes(bytes(data))
    assert image_header(bytes(data)) == (30000, 30000)
    with pytest.raises(DatasetError, match=r"30000x30000.*not decoded"):
        read_image(tmp_path / "bomb.jpg", size=(16, 16))
    with pytest.raises(DatasetError, match="more than"):
        read_image(tmp_path / "bomb.jpg")


@pytest.mark.parametrize("shape, dtype", [((20, 30), np.uint8), ((20, 30), np.uint16),
                                          ((20, 30, 3), np.uint8), ((20, 30, 4), np.uint16)])
def test_decoded_bytes_of_a_png_from_its_header(tmp_path: Path, shape, dtype) -> None:
    path = tmp_path / "f.png"
    cv2.imwrite(str(path), np.ones(shape, dtype))
    data = np.fromfile(path, np.uint8)
    decoded = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    assert decoded_bytes_bound(data, image_header(data)) == decoded.nbytes
