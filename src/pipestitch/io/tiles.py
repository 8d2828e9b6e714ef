"""Tiled pyramidal mosaic output, written incrementally (never the whole image in memory).

:func:`write_pyramid` takes the mosaic as blocks of columns (z ranges, left to right,
as a streaming stitcher produces them) and writes

* an OME-TIFF (BigTIFF, zlib tiles of ``tile`` x ``tile``) whose full-resolution image
  holds its reduced levels as SubIFDs (the layout QuPath, napari, Bio-Formats and
  ``tifffile.imread(path, level=k)`` read), and
* optionally a Deep Zoom tile folder (``mosaic.dzi`` + ``mosaic_files/<level>/
  <col>_<row>.png``, :func:`pipestitch.io.png.encode_png`) for the static viewer
  (report/viewer.py).

Blocks are cut into tile columns as they arrive; each full tile column is written out
(DZI tiles at once; TIFF tiles compressed at once to a scratch file, because TIFF stores
tiles row by row while the mosaic grows column by column) and averaged 2 x 2 into the
next level, which does the same. Memory: one tile column per level (rows x 2 tiles),
whatever the length of the mosaic. The scratch files (the compressed tiles, about 1.33
x the compressed image) live in a temporary folder next to the output and are removed
at the end; closing copies their tiles into the OME-TIFF in its order.

The TIFF tiles are deflated by ISA-L (``isal``, which releases the GIL) as they are cut,
on the thread that pushes the blocks: a zlib stream as any TIFF reader expects, in a
tenth of zlib's time at its default level for 1-4 % more bytes (a 1513 x 37160 mosaic:
0.12 against 0.95 s, 42.8 against 42.4 MB; docs/benchmarks.md). Compressing them all
when the pyramid closes, after the last block, held up the end of a run by that time.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np
import tifffile
from isal import isal_zlib

from pipestitch.io.atomic import atomic_path, atomic_write_text
from pipestitch.io.png import encode_png

__all__ = ["DZI_NAME", "PyramidInfo", "PyramidWriter", "level_shapes", "read_column_blocks",
           "read_dzi",
           "read_overview", "write_pyramid"]

DZI_NAME = "mosaic.dzi"


@dataclass(frozen=True)
class PyramidInfo:
    """What :func:`write_pyramid` wrote."""

    path: Path  # the OME-TIFF
    shape: tuple[int, ...]  # full resolution (rows, cols[, channels])
    tiff_levels: tuple[tuple[int, int], ...]  # (rows, cols) of each TIFF level
    tile: int
    dzi_path: Path | None  # tiles_dir / mosaic.dzi when a tile folder was written

_DZI_NS = "{http://schemas.microsoft.com/deepzoom/2008}"


def level_shapes(height: int, width: int) -> list[tuple[int, int]]:
    """(rows, cols) of each 2x level, from full resolution down to 1 x 1 (Deep Zoom)."""
    n_levels = math.ceil(math.log2(max(height, width, 1))) + 1
    return [(math.ceil(height / 2**k), math.ceil(width / 2**k)) for k in range(n_levels)]


def _halve(strip: np.ndarray) -> np.ndarray:
    """2 x 2 mean, odd sizes padded by edge replication (so sizes are ceil(n / 2))."""
    rows, cols = strip.shape[:2]
    pad = ((0, rows % 2), (0, cols % 2)) + ((0, 0),) * (strip.ndim - 2)
    padded = np.pad(strip, pad, mode="edge") if rows % 2 or cols % 2 else strip
    return cv2.resize(padded, (padded.shape[1] // 2, padded.shape[0] // 2),
                      interpolation=cv2.INTER_AREA).reshape(
        (padded.shape[0] // 2, padded.shape[1] // 2) + strip.shape[2:])


DEFLATE_LEVEL = 2   # ISA-L's levels are 0-3: 3 gave no fewer bytes, 1 up to 2 % more


class _TileStore:
    """A level's TIFF tiles, each deflated as it is added, in a scratch file in the
    order they come (tile columns); :meth:`row_major` gives them back in TIFF's order."""

    def __init__(self, handle: BinaryIO) -> None:
        self.handle = handle
        self.spans: list[tuple[int, int]] = []   # (offset, length) of each tile added
        self._end = 0

    def add(self, tile: np.ndarray) -> None:
        data = isal_zlib.compress(tile.tobytes(), DEFLATE_LEVEL)
        self.handle.write(data)
        self.spans.append((self._end, len(data)))
        self._end += len(data)

    def row_major(self, n_rows: int, n_cols: int) -> Iterator[bytes]:
        """The deflated tiles row by row (tile ``(tr, tc)`` was added as ``tc * n_rows + tr``)."""
        self.handle.flush()
        for tr in range(n_rows):
            for tc in range(n_cols):
                offset, length = self.spans[tc * n_rows + tr]
                self.handle.seek(offset)
                yield self.handle.read(length)

    def close(self) -> None:
        self.handle.close()


class _Level:
    """One pyramid level: buffers a tile column, writes its tiles, feeds the next level."""

    def __init__(self, index: int, shape: tuple[int, ...], tile: int, scratch: _TileStore | None,
                 dzi_dir: Path | None, below: _Level | None) -> None:
        self.index, self.shape, self.tile = index, shape, tile
        self.scratch, self.dzi_dir, self.below = scratch, dzi_dir, below
        self.buffer = np.zeros((shape[0], tile) + shape[2:], dtype=np.uint8)
        self.filled = 0
        self.tile_col = 0
        if dzi_dir is not None:
            dzi_dir.mkdir(parents=True, exist_ok=True)

    def push(self, block: np.ndarray) -> None:
        start = 0
        while start < block.shape[1]:
            take = min(self.tile - self.filled, block.shape[1] - start)
            self.buffer[:, self.filled:self.filled + take] = block[:, start:start + take]
            self.filled += take
            start += take
            if self.filled == self.tile:
                self._emit(self.buffer)

    def finish(self) -> None:
        if self.filled:
            self._emit(self.buffer[:, :self.filled])
        if self.below is not None:
            self.below.finish()

    def _emit(self, strip: np.ndarray) -> None:
        n_tile_rows = math.ceil(self.shape[0] / self.tile)
        for tr in range(n_tile_rows):
            part = strip[tr * self.tile:(tr + 1) * self.tile]
            if self.scratch is not None:
                padded = np.zeros((self.tile, self.tile) + strip.shape[2:], dtype=np.uint8)
                padded[:part.shape[0], :part.shape[1]] = part
                self.scratch.add(padded)
            if self.dzi_dir is not None:
                _write_png(self.dzi_dir / f"{self.tile_col}_{tr}.png", part)
        self.tile_col += 1
        if self.below is not None:
            self.below.push(_halve(strip))
        self.filled = 0


def _write_png(path: Path, image: np.ndarray) -> None:
    path.write_bytes(encode_png(image))   # colour tiles are given, and stored, as RGB


def _check_block(col0: int, block: np.ndarray, expected_col: int,
                 shape: tuple[int, ...]) -> None:
    if col0 != expected_col:
        raise ValueError(f"blocks must cover the columns left to right without gaps: "
                         f"expected col0 = {expected_col}, got {col0}")
    if block.shape[0] != shape[0] or block.shape[2:] != shape[2:] or block.dtype != np.uint8:
        expected = (shape[0], "w", *shape[2:])
        raise ValueError(f"expected uint8 blocks of shape {expected}, "
                         f"got {block.dtype} {block.shape}")
    if col0 + block.shape[1] > shape[1]:
        raise ValueError(f"block at col0 = {col0} of width {block.shape[1]} runs past the "
                         f"image width {shape[1]}")


def write_pyramid(path: str | Path, blocks: Iterable[tuple[int, np.ndarray]],
                  shape: tuple[int, ...], *, tile: int = 256,
                  tiles_dir: str | Path | None = None, mm_per_px: float | None = None,
                  ) -> PyramidInfo:
    """Write a mosaic given as column blocks as a pyramidal OME-TIFF (+ Deep Zoom tiles).

    Parameters
    ----------
    path : Path
        The OME-TIFF to write (atomically), e.g. ``OUT/mosaic.ome.tif``.
    blocks : iterable of (int, ndarray)
        ``(col0, block)``: uint8 blocks of shape (rows, w) or (rows, w, 3) (RGB), covering
        columns ``col0 .. col0 + w - 1``, left to right without gaps or overlaps.
        Consumed lazily: only the current block is held.
    shape : tuple
        Full image shape (rows, cols) or (rows, cols, 3).
    tile : int
        Tile edge in pixels (a multiple of 16, as TIFF requires).
    tiles_dir : Path, optional
        Also write a Deep Zoom tile folder there (``mosaic.dzi``, ``mosaic_files/``;
        replaced as a whole at the end).
    mm_per_px : float, optional
        Pixel size on the wall, written as the OME physical size.

    Returns
    -------
    PyramidInfo

    Raises
    ------
    ValueError
        If the blocks do not match ``shape`` or leave columns uncovered.
    """
    with PyramidWriter(path, shape, tile=tile, tiles_dir=tiles_dir,
                       mm_per_px=mm_per_px) as writer:
        for col0, block in blocks:
            writer.push(col0, block)
        return writer.close()


class PyramidWriter:
    """:func:`write_pyramid` as a sink: ``push(col0, block)`` as columns are ready, then
    ``close()``; leaving the ``with`` block without closing removes the scratch files and
    writes nothing (a failed run leaves no half-written pyramid).
    """

    def __init__(self, path: str | Path, shape: tuple[int, ...], *, tile: int = 256,
                 tiles_dir: str | Path | None = None, mm_per_px: float | None = None) -> None:
        shape = tuple(int(s) for s in shape)
        if len(shape) not in (2, 3) or shape[0] < 1 or shape[1] < 1 or tile % 16:
            raise ValueError(f"expected shape (rows, cols[, 3]) and a tile multiple of 16; "
                             f"got {shape}, {tile}")
        self.path, self.shape, self.tile, self.mm_per_px = Path(path), shape, tile, mm_per_px
        self.tiles_dir = Path(tiles_dir) if tiles_dir is not None else None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.shapes = [s + shape[2:] for s in level_shapes(shape[0], shape[1])]
        # TIFF levels until the image fits one tile; Deep Zoom needs every level to 1 x 1.
        self.n_tiff = next(k for k, s in enumerate(self.shapes) if max(s[:2]) <= tile) + 1
        self._scratch = tempfile.TemporaryDirectory(prefix=".pyramid.", dir=self.path.parent)
        scratch = Path(self._scratch.name)
        self._dzi_root = scratch / "dzi" if self.tiles_dir is not None else None
        self._stores = [_TileStore(open(scratch / f"level{k}.deflated", "w+b"))
                        for k in range(self.n_tiff)]
        self._top = _levels(self.shapes, tile, self._stores, self._dzi_root)
        self._col = 0

    def push(self, col0: int, block: np.ndarray) -> None:
        """Add the next column block (see :func:`write_pyramid`)."""
        block = np.asarray(block)
        _check_block(int(col0), block, self._col, self.shape)
        self._top.push(block)
        self._col += block.shape[1]

    def close(self) -> PyramidInfo:
        """Write the OME-TIFF (and move the tile folder into place); returns what was written."""
        if self._col != self.shape[1]:
            raise ValueError(f"blocks cover {self._col} columns, the image has {self.shape[1]}")
        self._top.finish()
        try:
            _write_tiff(self.path, self.shapes[:self.n_tiff], self._stores, self.tile,
                        self.mm_per_px)
            dzi_path = None
            if self.tiles_dir is not None and self._dzi_root is not None:
                atomic_write_text(self._dzi_root / DZI_NAME, _dzi_xml(self.shape, self.tile))
                dzi_path = _replace_dir(self._dzi_root, self.tiles_dir) / DZI_NAME
        finally:
            self.abort()
        return PyramidInfo(self.path, self.shape, tuple(s[:2] for s in self.shapes[:self.n_tiff]),
                           self.tile, dzi_path)

    def abort(self) -> None:
        """Remove the scratch files (idempotent)."""
        for store in self._stores:
            store.close()
        self._scratch.cleanup()

    def __enter__(self) -> PyramidWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.abort()


def _levels(shapes: list[tuple[int, ...]], tile: int, stores: list[_TileStore],
            dzi_root: Path | None) -> _Level:
    below = None
    top_dzi = len(shapes) - 1
    for k in range(len(shapes) - 1, -1, -1):
        dzi_dir = dzi_root / "mosaic_files" / str(top_dzi - k) if dzi_root is not None else None
        scratch = stores[k] if k < len(stores) else None
        if scratch is None and dzi_dir is None:
            continue
        below = _Level(k, shapes[k], tile, scratch, dzi_dir, below)
    assert below is not None  # level 0 always has a scratch file
    return below


def _write_tiff(path: Path, shapes: list[tuple[int, ...]], stores: list[_TileStore], tile: int,
                mm_per_px: float | None) -> None:
    axes = "YX" if len(shapes[0]) == 2 else "YXS"
    metadata: dict[str, object] = {"axes": axes, "Name": "pipestitch mosaic"}
    if mm_per_px is not None:
        um = float(mm_per_px) * 1000.0
        metadata.update(PhysicalSizeX=um, PhysicalSizeXUnit="µm",
                        PhysicalSizeY=um, PhysicalSizeYUnit="µm")
    common = {"dtype": np.uint8, "tile": (tile, tile), "compression": "zlib",
              "photometric": "minisblack" if axes == "YX" else "rgb"}
    def tiles(store: _TileStore, shape: tuple[int, ...]) -> Iterator[bytes]:
        return store.row_major(math.ceil(shape[0] / tile), math.ceil(shape[1] / tile))

    # tifffile writes an iterator of bytes as the tiles, already compressed
    with atomic_path(path) as tmp, tifffile.TiffWriter(tmp, bigtiff=True, ome=True) as tif:
        tif.write(tiles(stores[0], shapes[0]), shape=shapes[0], subifds=len(shapes) - 1,
                  metadata=metadata, **common)
        for store, level_shape in zip(stores[1:], shapes[1:], strict=True):
            tif.write(tiles(store, level_shape), shape=level_shape, subfiletype=1,
                      metadata=None, **common)


def read_overview(path: str | Path, max_pixels: int = 16_000_000) -> tuple[np.ndarray, int]:
    """The largest level of a pyramid written by :func:`write_pyramid` within a budget.

    Returns the image and its level k (a pixel of it is 2**k mosaic pixels on a side),
    e.g. for a ``mosaic.png`` overview of a mosaic too large to hold whole.
    """
    with tifffile.TiffFile(path) as tif:
        levels = tif.series[0].levels
        k = next((k for k, lv in enumerate(levels)
                  if lv.shape[0] * lv.shape[1] <= max_pixels), len(levels) - 1)
        return levels[k].asarray(), k


def read_column_blocks(path: str | Path) -> Iterator[tuple[int, np.ndarray]]:
    """The full-resolution image of a tiled TIFF as ``(col0, block)`` tile columns.

    Decodes one column of tiles at a time, so memory is rows x tile width whatever the
    length of the mosaic (the way ``pipestitch measure`` reads a long run's mosaic).

    Raises
    ------
    ValueError
        If the file's first page is not tiled.
    """
    with tifffile.TiffFile(path) as tif:
        page = tif.pages.first
        if not page.is_tiled:
            raise ValueError(f"{path}: not a tiled TIFF")
        rows, cols = page.shape[:2]
        th, tw = page.tilelength, page.tilewidth
        n_down, n_across = math.ceil(rows / th), math.ceil(cols / tw)
        decode = page.decode
        for tc in range(n_across):
            width = min(tw, cols - tc * tw)
            block = np.empty((rows, width) + page.shape[2:], page.dtype)
            for tr in range(n_down):
                index = tr * n_across + tc
                tif.filehandle.seek(page.dataoffsets[index])
                data = tif.filehandle.read(page.databytecounts[index])
                tile = decode(data, index)[0].reshape((th, tw) + page.shape[2:])
                height = min(th, rows - tr * th)
                block[tr * th:tr * th + height] = tile[:height, :width]
            yield tc * tw, block


def _dzi_xml(shape: tuple[int, ...], tile: int) -> str:
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<Image xmlns="http://schemas.microsoft.com/deepzoom/2008" Format="png" '
            f'Overlap="0" TileSize="{tile}">\n'
            f'  <Size Width="{shape[1]}" Height="{shape[0]}"/>\n</Image>\n')


def _replace_dir(src: Path, dest: Path) -> Path:
    """Move a finished folder into place; an older one of that name is removed after."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    old = None
    if dest.exists():
        old = dest.with_name(f".{dest.name}.old.{os.getpid()}")
        os.replace(dest, old)
    shutil.move(str(src), str(dest))
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return dest


def read_dzi(dzi_path: str | Path) -> dict[str, object]:
    """A Deep Zoom ``.dzi`` file as OpenSeadragon's inline tile source.

    Raises
    ------
    ValueError
        Naming the file when it is not a Deep Zoom description.
    """
    dzi_path = Path(dzi_path)
    try:
        root = ET.fromstring(dzi_path.read_text(encoding="utf-8"))
        size = root.find(f"{_DZI_NS}Size")
        width, height = int(size.get("Width")), int(size.get("Height"))
        fmt, tile = root.get("Format"), int(root.get("TileSize"))
        overlap = int(root.get("Overlap", "0"))
    except (OSError, ET.ParseError, AttributeError, TypeError, ValueError) as exc:
        raise ValueError(f"{dzi_path}: not a Deep Zoom description ({exc})") from exc
    return {"Image": {"xmlns": "http://schemas.microsoft.com/deepzoom/2008",
                      "Format": fmt, "Overlap": str(overlap), "TileSize": str(tile),
                      "Size": {"Width": str(width), "Height": str(height)}}}
