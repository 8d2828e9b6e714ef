"""Reading and writing frames: 8- or 16-bit, grey or colour, with clear errors.

A frame's size is read from its header before its pixels are decoded (PNG's IHDR, a
TIFF's first page tags, a JPEG's frame header), so a file that declares a size other
than the camera's, or more pixels than ``MAX_PIXELS``, is refused at the cost of reading
a few bytes, whatever it would take to decode: a small file declaring 30000 x 30000
pixels never becomes a gigabyte of memory. PNGs in the layouts cameras write are
decoded by :mod:`pipestitch.io.png` (the same pixels, in less than half the time);
other files by OpenCV within its own pixel limit.
"""

from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
import tifffile

from pipestitch.errors import DatasetError
from pipestitch.io import ahead
from pipestitch.io.atomic import atomic_write_bytes
from pipestitch.io.filebytes import file_bytes
from pipestitch.io.png import SIGNATURE as PNG_SIGNATURE
from pipestitch.io.png import decode_png

__all__ = ["MAX_PIXELS", "decoded_bytes_bound", "image_header", "read_image", "write_image"]

MAX_PIXELS = 2**27   # 134 Mpx: 10x a 12 MP sensor; larger frames are refused unread
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}   # frame headers, not tables
# IHDR colour type -> channels of OpenCV's IMREAD_UNCHANGED decoding (palette as BGR,
# grey with alpha as BGRA)
_PNG_DECODED_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 4, 6: 4}
# Decoded bytes a pixel may take where the header does not say: a JPEG up to four 16-bit
# components, anything else (TIFF) up to four 32-bit ones.
_JPEG_BYTES_BOUND, _OTHER_BYTES_BOUND = 8, 16


def image_header(data: bytes | np.ndarray) -> tuple[int, int] | None:
    """(width, height) an image file declares, read without decoding its pixels.

    PNG, TIFF and JPEG are read; None for other formats (or a header too short to tell).
    """
    head = bytes(data[:33]) if isinstance(data, bytes) else data[:33].tobytes()
    if head.startswith(PNG_SIGNATURE) and head[12:16] == b"IHDR" and len(head) >= 24:
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        try:
            with tifffile.TiffFile(io.BytesIO(bytes(data))) as tif:
                page = tif.pages[0]   # its tags (planar or volume layouts alike)
                return int(page.imagewidth), int(page.imagelength)
        except Exception:   # any malformed TIFF: the decoder says so
            return None
    if head[:2] == b"\xff\xd8":
        return _jpeg_size(bytes(data[:65536]) if not isinstance(data, bytes) else data[:65536])
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's frame header (SOFn), walking its marker segments."""
    pos = 2
    while pos + 9 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:   # fill byte
            pos += 1
            continue
        length = int.from_bytes(data[pos + 2:pos + 4], "big")
        if marker in _JPEG_SOF:
            return (int.from_bytes(data[pos + 7:pos + 9], "big"),
                    int.from_bytes(data[pos + 5:pos + 7], "big"))
        pos += 2 + length
    return None


def decoded_bytes_bound(data: bytes | np.ndarray, declared: tuple[int, int]) -> int:
    """Most bytes ``cv2.imdecode(data, IMREAD_UNCHANGED)`` makes of a file that declares
    ``declared`` (width, height, :func:`image_header`): exact for a PNG (its bit depth and
    colour type), a bound for other formats."""
    head = bytes(data[:26]) if isinstance(data, bytes) else data[:26].tobytes()
    pixels = declared[0] * declared[1]
    if head.startswith(PNG_SIGNATURE) and len(head) >= 26:
        return (pixels * _PNG_DECODED_CHANNELS.get(head[25], 4)
                * (2 if head[24] == 16 else 1))
    return pixels * (_JPEG_BYTES_BOUND if head[:2] == b"\xff\xd8" else _OTHER_BYTES_BOUND)


def read_image(path: str | Path, *, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image unchanged (dtype and channels as stored; colour as BGR).

    Parameters
    ----------
    path : path
        The image file.
    size : (int, int), optional
        The (width, height) the image must have: checked against the file's header
        before decoding (PNG, TIFF), then against the decoded image.

    Raises
    ------
    DatasetError
        If the file is missing, empty, declares another size or more than
        ``MAX_PIXELS`` pixels, or cannot be decoded.
    """
    path = Path(path)
    decoded = ahead.take(path)   # decoded while the command started (io/ahead.py)
    if decoded is not None:
        declared, img = decoded
        _check_declared(path, declared, size)
    else:
        img = _decoded(path, size)
    if img.dtype not in (np.uint8, np.uint16):
        raise DatasetError(path, f"expected 8- or 16-bit pixels, got {img.dtype}")
    if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
        raise DatasetError(path, f"image is {img.shape[1]}x{img.shape[0]}, probe.toml says "
                                 f"{size[0]}x{size[1]}")
    return img


def _decoded(path: Path, size: tuple[int, int] | None) -> np.ndarray:
    """The file's pixels, its declared size checked before decoding."""
    if not path.is_file():
        raise DatasetError(path, "file not found")
    data = file_bytes(path)
    if data.size == 0:
        raise DatasetError(path, "file is empty")
    declared = image_header(data)
    if declared is not None:
        _check_declared(path, declared, size)
    img = decode_png(data)   # the layouts cameras write, faster; else None (io/png.py)
    if img is not None:
        return img
    try:
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:   # e.g. beyond OpenCV's own pixel limit
        raise DatasetError(path, f"cannot decode image ({str(exc).strip().splitlines()[-1]})"
                           ) from None
    if img is None:
        raise DatasetError(path, "cannot decode image (corrupt or not an image)")
    return img


def _check_declared(path: Path, declared: tuple[int, int], size: tuple[int, int] | None) -> None:
    width, height = declared
    if size is not None and (width, height) != tuple(size):
        raise DatasetError(path, f"image is {width}x{height}, probe.toml says "
                                 f"{size[0]}x{size[1]} (from its header; not decoded)")
    if width * height > MAX_PIXELS:
        raise DatasetError(path, f"image declares {width}x{height} pixels, more than "
                                 f"{MAX_PIXELS:,} ; not decoded")


def write_image(path: str | Path, img: np.ndarray) -> Path:
    """Write a PNG (or any format OpenCV knows by extension) atomically."""
    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", img)
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the image")
    return atomic_write_bytes(path, buf.tobytes())
