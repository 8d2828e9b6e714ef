"""PNG frames decoded to the same pixels as OpenCV's decoder gives, in less than half
its time.

Why hand-written: decoding is the floor under a run's time (every frame is read at
least once), and OpenCV inflates a PNG with zlib and unfilters it through libpng's row
callbacks: 7.0 ms for a 1224 x 1024 grey frame on a 2-core machine, of which inflating
is 4 ms. ISA-L's inflate (``isal``, which releases the GIL) takes 2.2 ms and a compiled
unfilter (:func:`pipestitch.io._image_kernels.png_unfilter`) 0.35 ms, 2.8 ms in all
(docs/benchmarks.md). No decoder library we found is faster than OpenCV's here
(imagecodecs' libpng and libspng take 6.8 and 7.3 ms). The stream is inflated to the
image's size and a byte more at most, whatever it holds. Those figures are for OpenCV's
files (every row Sub-filtered). Pillow (and imageio, which writes PNGs through it)
chooses a filter for each row: a textured LED frame's rows came out nearly all Paeth,
which unfilter in 1.1-1.2 ms (a grey 1224 x 1024 frame: OpenCV decodes such a file in
~12 ms, this reader in ~3.3 ms), a mostly dark laser frame's Up and Sub.

Only the layouts cameras write are decoded here: 8- or 16-bit grey, RGB or RGBA, not
interlaced, whose chunks are the image's own (IHDR, IDAT, IEND) or ancillary ones that
OpenCV's decoding leaves the pixels alone for (text, time, physical size, colour space,
background, significant bits). Anything else (palette, grey with alpha, fewer bits,
interlacing, transparency, animation, EXIF, an unknown chunk) and any file this reader
finds malformed (a chunk past the end of the file, a CRC that does not match, a zlib
stream that does not inflate to the image's size, an unknown filter) gets None, and
OpenCV decodes it or refuses it as it always did. So whichever decoder reads a frame,
the pixels, and the errors, are OpenCV's.

The mosaic's 8-bit PNGs (the viewer's tiles, ``mosaic.png``) are written by
:func:`encode_png`: every scanline Paeth-filtered by a compiled loop
(:func:`pipestitch.io._image_kernels.png_paeth_filter`) and deflated by ISA-L at level
1. OpenCV's encoder (libpng and zlib at level 1, a filter chosen for each row by
trying all five) took 1.1-1.5 ms for a 256 x 256 tile of a mosaic; this one 0.15 ms,
and its files came out 3-7 % smaller on four scenarios' mosaics (docs/benchmarks.md).
"""

from __future__ import annotations

import struct
import sys

import cv2
import numpy as np
from isal import isal_zlib

__all__ = ["decode_png", "encode_png"]

SIGNATURE = b"\x89PNG\r\n\x1a\n"
CHANNELS = {0: 1, 2: 3, 6: 4}   # IHDR colour type -> samples a pixel (grey, RGB, RGBA)
DEFLATE_LEVEL = 1   # ISA-L's (0-3): 2 and 3 gave the tiles no fewer bytes
# OpenCV's order: colour as BGR(A)
TO_OPENCV = {3: cv2.COLOR_RGB2BGR, 4: cv2.COLOR_RGBA2BGRA}
# Ancillary chunks that leave OpenCV's pixels as stored (IMREAD_UNCHANGED applies no
# gamma, colour profile, background or bit shift)
PASSIVE = frozenset({b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs", b"gAMA", b"cHRM",
                     b"sRGB", b"iCCP", b"bKGD", b"sBIT"})


def decode_png(data: bytes | np.ndarray) -> np.ndarray | None:
    """A PNG file's pixels as ``cv2.imdecode(data, cv2.IMREAD_UNCHANGED)`` gives them, or
    None where this reader leaves the file to OpenCV (see the module docstring).

    Parameters
    ----------
    data : bytes or numpy.ndarray
        The whole file (a uint8 array as ``numpy.fromfile`` reads it, or bytes).

    Returns
    -------
    numpy.ndarray or None
        uint8 or uint16, (H, W) grey or (H, W, 3|4) BGR(A); None as said.
    """
    array = np.ascontiguousarray(data) if isinstance(data, np.ndarray) else data
    found = _image_chunks(memoryview(array).cast("B"))
    if found is None:
        return None
    (width, height, depth, colour), stream = found
    channels = CHANNELS[colour]
    pixel_bytes = channels * depth // 8
    row_bytes = width * pixel_bytes
    size = height * (row_bytes + 1)
    try:   # one byte more than the image's at most: a stream that inflates to more ...
        raw = isal_zlib.decompressobj().decompress(stream, size + 1)
    except Exception:   # not a zlib stream, or a truncated one: OpenCV's verdict
        return None
    if len(raw) != size:   # ... or to less is OpenCV's to judge
        return None
    # numba, imported here: reading the images module stays light (io/ahead.py's thread
    # reads it while the command's own imports load numba)
    from pipestitch.io._image_kernels import png_unfilter

    out = np.empty(height * row_bytes, np.uint8)
    if not png_unfilter(np.frombuffer(raw, np.uint8), height, row_bytes, pixel_bytes, out):
        return None
    # in place from here: a frame's bytes are held twice at most (the stream and these)
    pixels = out.view(np.uint16) if depth == 16 else out
    if depth == 16 and sys.byteorder == "little":
        pixels.byteswap(inplace=True)   # PNG's samples are big-endian
    image = pixels.reshape((height, width) if channels == 1 else (height, width, channels))
    return cv2.cvtColor(image, TO_OPENCV[channels], dst=image) if channels > 1 else image


def encode_png(image: np.ndarray) -> bytes:
    """A PNG file of an 8-bit grey (H, W) or RGB (H, W, 3) image (not OpenCV's BGR: the
    channels are stored in the order given), every scanline Paeth-filtered, in one IDAT
    chunk.

    Parameters
    ----------
    image : numpy.ndarray
        uint8, (H, W) or (H, W, 3), at least one pixel.

    Returns
    -------
    bytes
        The whole file.

    Raises
    ------
    ValueError
        For another type or shape.
    """
    image = np.asarray(image)
    if (image.dtype != np.uint8 or image.ndim not in (2, 3) or 0 in image.shape
            or (image.ndim == 3 and image.shape[2] != 3)):
        raise ValueError(f"encode_png: expected uint8 (H, W) or (H, W, 3), got "
                         f"{image.dtype} {image.shape}")
    from pipestitch.io._image_kernels import png_paeth_filter  # numba: as decode_png

    height, width = image.shape[:2]
    channels = 1 if image.ndim == 2 else 3
    rows = np.ascontiguousarray(image).reshape(height, width * channels).view()
    rows.flags.writeable = False   # the kernel's one signature (read-only), whatever came
    stream = isal_zlib.compress(png_paeth_filter(rows, channels), DEFLATE_LEVEL)
    header = struct.pack(">IIBBBBB", width, height, 8, 0 if channels == 1 else 2, 0, 0, 0)
    return b"".join([SIGNATURE, _chunk(b"IHDR", header), _chunk(b"IDAT", stream),
                     _chunk(b"IEND", b"")])


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(
        ">I", isal_zlib.crc32(kind + body))


def _image_chunks(buffer: memoryview) -> tuple[tuple[int, int, int, int], bytes] | None:
    """The header (width, height, bit depth, colour type) and the joined IDAT data of a
    PNG this reader decodes, or None (see the module docstring)."""
    if buffer[:len(SIGNATURE)] != SIGNATURE:
        return None
    pos, header, parts, idat_done = len(SIGNATURE), None, [], False
    while pos + 12 <= len(buffer):
        length, kind = struct.unpack_from(">I4s", buffer, pos)   # (a view: no copies)
        end = pos + 8 + length
        if end + 4 > len(buffer) or (isal_zlib.crc32(buffer[pos + 4:end])
                                     != struct.unpack_from(">I", buffer, end)[0]):
            return None
        body = buffer[pos + 8:end]
        if header is None:
            header = _header(body) if kind == b"IHDR" else None
            if header is None:
                return None
        elif kind == b"IDAT":
            if idat_done:
                return None   # IDAT chunks must be consecutive
            parts.append(body)
        elif kind == b"IEND":
            return (header, b"".join(parts)) if parts else None
        elif kind in PASSIVE:
            idat_done = bool(parts)
        else:
            return None
        pos = end + 4
    return None   # no IEND


def _header(body: memoryview) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) of an IHDR this reader decodes, else None."""
    if len(body) != 13:
        return None
    width, height, depth, colour, compression, filtering, interlace = struct.unpack(
        ">IIBBBBB", body)
    if (width == 0 or height == 0 or depth not in (8, 16) or colour not in CHANNELS
            or compression or filtering or interlace):
        return None
    return width, height, depth, colour
