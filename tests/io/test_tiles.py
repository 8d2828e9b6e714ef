"""Tiled pyramidal output: OME-TIFF levels and Deep Zoom tiles against independently
computed truth, from blocks of any width, and bad input."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from pipestitch.io.tiles import (
    PyramidWriter,
    level_shapes,
    read_column_blocks,
    read_overview,
    write_pyramid,
)


def _blocks(image: np.ndarray, widths: list[int]):
    col = 0
    for w in widths:
        yield col, image[:, col:col + w]
        col += w


def _reference_level(image: np.ndarray, k: int) -> np.ndarray:
    """Level k by repeated 2 x 2 means of the whole image (edge-replicated odd sizes),
    in float: an independent, whole-image computation."""
    out = image.astype(np.float64)
    for _ in range(k):
        r, c = out.shape[:2]
        out = np.pad(out, ((0, r % 2), (0, c % 2)) + ((0, 0),) * (out.ndim - 2), mode="edge")
        out = out.reshape(out.shape[0] // 2, 2, out.shape[1] // 2, 2, *out.shape[2:])
        out = out.mean(axis=(1, 3))
    return out


@pytest.mark.parametrize("shape", [(300, 1000), (257, 513, 3)])
def test_pyramid_levels_and_tiles_match_the_image(tmp_path: Path, shape) -> None:
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.integers(0, 256, shape, dtype=np.uint8), (0, 0), 1.5)
    widths = rng.integers(1, 300, 40).tolist()
    widths = [w for w in np.diff(np.r_[0, np.minimum(np.cumsum(widths), shape[1])]) if w]
    if sum(widths) < shape[1]:
        widths.append(shape[1] - sum(widths))
    info = write_pyramid(tmp_path / "m.ome.tif", _blocks(image, widths), shape,
                         tile=128, tiles_dir=tmp_path / "tiles", mm_per_px=0.135)
    with tifffile.TiffFile(info.path) as tif:
        assert tif.is_ome
        levels = tif.series[0].levels
        assert len(levels) == len(info.tiff_levels) >= 3
        assert np.array_equal(levels[0].asarray(), image)
        for k, level in enumerate(levels):
            got = level.asarray()
            assert got.shape[:2] == (math.ceil(shape[0] / 2**k), math.ceil(shape[1] / 2**k))
            # Each level is made from the rounded level above, so rounding adds up to
            # 0.5 grey level per level; the mean error stays far below that.
            err = np.abs(got - _reference_level(image, k))
            assert err.max() <= 0.5 * k + 1e-9 and err.mean() < 0.5
        assert max(levels[-1].shape[:2]) <= 128
        assert 'PhysicalSizeX="135.0"' in tif.ome_metadata
    dzi = ET.parse(tmp_path / "tiles" / "mosaic.dzi").getroot()
    size = dzi.find("{http://schemas.microsoft.com/deepzoom/2008}Size")
    assert (int(size.get("Width")), int(size.get("Height"))) == (shape[1], shape[0])
    files = tmp_path / "tiles" / "mosaic_files"
    n_levels = len(level_shapes(shape[0], shape[1]))
    assert sorted(int(p.name) for p in files.iterdir()) == list(range(n_levels))
    top = n_levels - 1
    tile = cv2.imread(str(files / str(top) / "1_1.png"), cv2.IMREAD_UNCHANGED)
    expected = image[128:256, 128:256]
    if tile.ndim == 3:
        tile = tile[..., ::-1]  # PNG read as BGR; the image is RGB
    assert np.array_equal(tile, expected)
    smallest = cv2.imread(str(files / "0" / "0_0.png"), cv2.IMREAD_UNCHANGED)
    assert smallest.shape[:2] == (1, 1)
    # Overview: the largest level within the pixel budget (level 2 holds ~1/16).
    overview, k = read_overview(info.path, max_pixels=shape[0] * shape[1] // 10)
    assert k == 2 and overview.shape[:2] == info.tiff_levels[2]


def test_level_shapes_go_down_to_one_pixel() -> None:
    shapes = level_shapes(1500, 40000)
    assert shapes[0] == (1500, 40000) and shapes[-1] == (1, 1)
    assert len(shapes) == math.ceil(math.log2(40000)) + 1


def test_bad_blocks_are_rejected(tmp_path: Path) -> None:
    image = np.zeros((64, 100), np.uint8)
    with pytest.raises(ValueError, match="without gaps"):
        write_pyramid(tmp_path / "a.tif", [(0, image[:, :40]), (50, image[:, 50:])],
                      image.shape)
    with pytest.raises(ValueError, match="cover 40 columns"):
        write_pyramid(tmp_path / "b.tif", [(0, image[:, :40])], image.shape)
    with pytest.raises(ValueError, match="uint8 blocks"):
        write_pyramid(tmp_path / "c.tif", [(0, image.astype(np.uint16))], image.shape)
    with pytest.raises(ValueError, match="runs past"):
        write_pyramid(tmp_path / "d.tif", [(0, np.zeros((64, 120), np.uint8))], image.shape)
    assert not any(tmp_path.iterdir())  # nothing half-written left behind


def test_pyramid_writer_streams_blocks_and_reads_back_by_tile_columns(tmp_path: Path) -> None:
    image = (np.arange(300 * 700).reshape(300, 700) % 251 + 1).astype(np.uint8)
    with PyramidWriter(tmp_path / "m.ome.tif", image.shape, tile=64) as writer:
        for c in range(0, 700, 90):
            writer.push(c, image[:, c:c + 90])
        info = writer.close()
    blocks = list(read_column_blocks(info.path))
    assert [c for c, _ in blocks] == list(range(0, 700, 64))
    assert np.array_equal(np.concatenate([b for _, b in blocks], axis=1), image)


def test_pyramid_writer_left_unclosed_leaves_nothing(tmp_path: Path) -> None:
    image = np.ones((64, 100), np.uint8)
    with pytest.raises(RuntimeError), PyramidWriter(tmp_path / "m.ome.tif", image.shape,
                                                    tile=32, tiles_dir=tmp_path / "t") as w:
        w.push(0, image[:, :50])
        raise RuntimeError("the run failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
