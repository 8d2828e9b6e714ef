"""The mosaic's outputs, written while it is stitched (memory bounded whatever the run).

:class:`StreamedMosaic` is the sink :func:`pipestitch.pipeline.stitching.build_mosaic`
releases finished canvas columns to. Each block is converted to 8 bits and goes at
once to

* the pyramidal OME-TIFF ``mosaic.ome.tif`` and the viewer's Deep Zoom ``tiles/``
  (:class:`pipestitch.io.tiles.PyramidWriter`): the full-resolution mosaic;
* the overview that becomes ``mosaic.png`` (:class:`pipestitch.mosaic.blend.Overview`): the
  whole mosaic while it fits ``OVERVIEW_PIXELS``, else reduced by an integer factor,
  its scale in ``mosaic.json`` (the full resolution's under ``full_resolution``);
* the defect measurement (:class:`pipestitch.measure.blocks.BlockDefects`) on the
  same 8-bit values that the OME-TIFF holds, so ``pipestitch measure`` finds exactly
  the same defects.

The 8-bit scale (the 99.5th percentile mapped to 250) is set from the first
``SCALE_COLS`` columns (all of a shorter mosaic), which are held until then.

The writing (pyramid and overview) and the defect measurement each run on a thread
of their own, in block order (at most ``AHEAD`` blocks wait for them): the stitch,
which releases the blocks, goes on blending meanwhile instead of waiting for the
encoders, and a mosaic shorter than ``SCALE_COLS``, all written and measured when the
stitch ends, keeps both cores busy.
"""

from __future__ import annotations

import os
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipestitch.geometry import WallGrid
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.outputs import intensity_scale, mosaic_from_uint8, mosaic_to_uint8
from pipestitch.io.tiles import PyramidWriter, read_dzi
from pipestitch.measure.blocks import BlockDefects
from pipestitch.measure.defects import Defect
from pipestitch.mosaic.blend import Overview
from pipestitch.pipeline.progress import StageTimer
from pipestitch.report.viewer import VIEWER_NAME, render_viewer

__all__ = ["OVERVIEW_PIXELS", "PYRAMID", "SCALE_COLS", "TILES", "StreamedMosaic",
           "WrittenMosaic", "write_viewer"]

PYRAMID = "mosaic.ome.tif"
TILES = "tiles"
SCALE_COLS = 4096
OVERVIEW_PIXELS = 16_000_000
AHEAD = 8     # blocks (8-bit, ~1.5 MB at full size) waiting for the writing and the measurement


@dataclass(frozen=True)
class WrittenMosaic:
    """What :meth:`StreamedMosaic.finish` returns."""

    grid: WallGrid             # full resolution (mosaic.ome.tif)
    overview: np.ndarray       # mosaic.png (8-bit, 0 = no data)
    overview_grid: WallGrid
    factor: int                # overview pixel = factor x factor mosaic pixels
    intensity_scale: float
    defects: list[Defect]
    radius_mm: float


class StreamedMosaic:
    """Sink for :func:`build_mosaic`: pyramid, overview and defects from column blocks.

    Use as a context manager: leaving it without :meth:`finish` (a failed run) removes
    the pyramid's scratch files and writes nothing.
    """

    def __init__(self, out: Path, timer: StageTimer | None = None, *,
                 overview_pixels: int | None = None) -> None:
        self.out, self.timer = Path(out), timer or StageTimer()
        self.overview_pixels = overview_pixels or OVERVIEW_PIXELS
        self.scale: float | None = None
        self._held: list[tuple[int, np.ndarray]] = []
        self._pyramid: PyramidWriter | None = None
        self._writing = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mosaic-writer")
        self._measuring = ThreadPoolExecutor(max_workers=1, thread_name_prefix="defects")
        self._pending: deque[Future[None]] = deque()
        self._aborted = False

    def start(self, grid: WallGrid, radius_mm: float) -> None:
        """Open the outputs for a canvas ``grid`` (see MosaicSink)."""
        self.grid, self.radius_mm = grid, radius_mm
        self._pyramid = PyramidWriter(self.out / PYRAMID, (grid.n_rows, grid.n_cols),
                                      tiles_dir=self.out / TILES, mm_per_px=grid.mm_per_px_axial)
        self._overview = Overview(grid, self.overview_pixels)
        self._defects = BlockDefects(grid)

    def push(self, col0: int, image: np.ndarray, weights: np.ndarray) -> None:
        """Finished columns (float, NaN where no data); see MosaicSink."""
        if self.scale is not None:
            self._emit(col0, image)
            return
        self._held.append((col0, image))
        if sum(b.shape[1] for _, b in self._held) >= SCALE_COLS:
            self._release_held()

    def _release_held(self) -> None:
        data = np.concatenate([b for _, b in self._held], axis=1) if self._held else None
        self.scale = intensity_scale(data) if data is not None else 1.0
        del data
        held, self._held = self._held, []
        for col0, block in held:
            self._emit(col0, block)

    def _emit(self, col0: int, image: np.ndarray) -> None:
        with self.timer("write"):
            block, _ = mosaic_to_uint8(image, self.scale)
        self._pending.append(self._writing.submit(self._write, col0, block))
        self._pending.append(self._measuring.submit(self._measure, col0, block))
        while len(self._pending) > 2 * AHEAD:
            self._pending.popleft().result()   # in order; raises what the thread raised

    def _write(self, col0: int, block: np.ndarray) -> None:
        with self.timer("write"):
            assert self._pyramid is not None
            self._pyramid.push(col0, block)
            self._overview.push(block)

    def _measure(self, col0: int, block: np.ndarray) -> None:
        with self.timer("measure"):
            self._defects.push(col0, mosaic_from_uint8(block))

    def _defects_found(self) -> list[Defect]:
        with self.timer("measure"):
            return self._defects.finish()

    def _closed(self) -> np.ndarray | None:
        if self._aborted:   # a block failed or the run was stopped: write nothing
            return None
        with self.timer("write"):
            assert self._pyramid is not None
            self._pyramid.close()
            return self._overview.finish()

    def finish(self) -> WrittenMosaic:
        """Write the last columns and close the pyramid; the overview and the defects."""
        if self.scale is None:
            self._release_held()
        assert self._pyramid is not None and self.scale is not None
        # each thread closes after its queued blocks (in order), the two side by side
        overview = self._writing.submit(self._closed)
        defects = self._measuring.submit(self._defects_found)
        while self._pending:   # the blocks first: their errors are the cause
            self._pending.popleft().result()
        closed = overview.result()
        assert closed is not None
        return WrittenMosaic(self.grid, closed, self._overview.grid,
                             self._overview.factor, self.scale, defects.result(),
                             self.radius_mm)

    def abort(self) -> None:
        """Drop everything written so far (idempotent): queued blocks and the closing
        writes are cancelled; a block being written or measured is waited for."""
        self._aborted = True
        self._writing.shutdown(wait=True, cancel_futures=True)
        self._measuring.shutdown(wait=True, cancel_futures=True)
        if self._pyramid is not None:
            self._pyramid.abort()

    def __enter__(self) -> StreamedMosaic:
        return self

    def __exit__(self, *exc: object) -> None:
        self.abort()


def write_viewer(out_dir: str | Path, tiles_dir: str | Path, *, title: str = "pipestitch mosaic",
                 z0_mm: float = 0.0, mm_per_px: float | None = None,
                 deg_per_px: float | None = None) -> Path:
    """Write ``out_dir/viewer.html`` showing the Deep Zoom tiles in ``tiles_dir``.

    The page refers to the tiles relative to its own folder (it does not copy them).

    Raises
    ------
    ValueError
        If ``tiles_dir`` holds no readable ``mosaic.dzi``.
    """
    out_dir, tiles_dir = Path(out_dir), Path(tiles_dir)
    source = read_dzi(tiles_dir / "mosaic.dzi")
    relative = Path(os.path.relpath(tiles_dir.resolve(), out_dir.resolve()))
    source["Image"]["Url"] = (relative / "mosaic_files").as_posix() + "/"
    page = render_viewer(source, title=title, z0_mm=z0_mm, mm_per_px=mm_per_px,
                         deg_per_px=deg_per_px)
    return atomic_write_text(out_dir / VIEWER_NAME, page)
