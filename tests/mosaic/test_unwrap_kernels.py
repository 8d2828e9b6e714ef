"""The compiled unwrapping kernels against the numpy/OpenCV expressions they replace
(written out again here).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.imaging import gaussian_blur
from pipestitch.mosaic._unwrap_kernels import (
    MapFields,
    mask_strip,
    upsample_maps,
)
from pipestitch.mosaic.unwrap import local_contrast

RNG = np.random.default_rng(7)


def _bilinear(nodes: np.ndarray, step: int, n_rows: int, n_cols: int) -> np.ndarray:
    """Exact bilinear interpolation (float64) of (F, rows, cols) nodes every ``step``."""
    r = np.arange(n_rows) / step
    c = np.arange(n_cols) / step
    r0 = np.minimum(np.floor(r).astype(int), nodes.shape[1] - 2)
    c0 = np.minimum(np.floor(c).astype(int), nodes.shape[2] - 2)
    fr, fc = (r - r0)[:, None], (c - c0)[None, :]
    a = nodes.astype(float)
    return (a[:, r0][:, :, c0] * (1 - fr) * (1 - fc) + a[:, r0 + 1][:, :, c0] * fr * (1 - fc)
            + a[:, r0][:, :, c0 + 1] * (1 - fr) * fc + a[:, r0 + 1][:, :, c0 + 1] * fr * fc)


@pytest.mark.parametrize(("n_rows", "n_cols", "step"), [(37, 29, 4), (40, 33, 4), (21, 22, 3)])
def test_upsampled_maps_are_bilinear_and_masked_where_any_node_is_invalid(
        n_rows: int, n_cols: int, step: int) -> None:
    n_r, n_c = -(-(n_rows - 1) // step) + 1, -(-(n_cols - 1) // step) + 1
    nodes = (RNG.normal(size=(5, n_r, n_c)) * 100).astype(np.float32)
    nodes[2] = 1.0
    nodes[2, 3, 2] = 0.0                      # one invalid node
    out = upsample_maps(MapFields(*nodes), step=step, n_rows=n_rows, n_cols=n_cols,
                        ok_above=0.999)
    ref = MapFields(*_bilinear(nodes, step, n_rows, n_cols))
    bad = ref.valid <= 0.999
    # Invalid: every output node the invalid node contributes to, and only those.
    rows, cols = np.nonzero(bad)
    assert rows.min() > (3 - 1) * step and rows.max() < (3 + 1) * step
    assert cols.min() > (2 - 1) * step and cols.max() < (2 + 1) * step
    assert out.valid is None   # the mask applied instead
    for name, fill in (("map_x", -1.0), ("map_y", -1.0), ("quality", 0.0), ("shading", 0.0)):
        got, want = getattr(out, name), getattr(ref, name)
        assert got.shape == (n_rows, n_cols)
        assert np.all(got[bad] == fill)
        # float32 arithmetic on values ~100: a few 1e-5 relative.
        np.testing.assert_allclose(got[~bad], want[~bad], rtol=0, atol=1e-3)
    # Absent fields stay absent; the maps are the same without them.
    maps_only = upsample_maps(MapFields(*nodes[:3]), step=step, n_rows=n_rows, n_cols=n_cols,
                              ok_above=0.999)
    assert maps_only.quality is None and maps_only.shading is None
    np.testing.assert_array_equal(maps_only.map_x, out.map_x)
    np.testing.assert_array_equal(maps_only.map_y, out.map_y)


def test_strip_mask_uses_the_nearest_pixel_as_cv2_remap_does() -> None:
    # 30 columns: the packed mask's last byte holds 6 pixels and 2 pad bits
    occluded = RNG.random((20, 30)) < 0.3
    # Half-integer coordinates (rounded to even), out of the frame, and invisible nodes.
    map_x = (RNG.integers(-4, 66, (15, 17)) / 2).astype(np.float32)
    map_y = (RNG.integers(-4, 46, (15, 17)) / 2).astype(np.float32)
    map_x[0, :3] = -1
    values = RNG.random(map_x.shape).astype(np.float32)
    values[1, :2] = np.nan
    quality = RNG.random(map_x.shape).astype(np.float32)
    hidden = cv2.remap(occluded.astype(np.uint8), map_x, map_y, cv2.INTER_NEAREST,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=1).astype(bool)
    bad = ~np.isfinite(values) | (quality < 0.4) | hidden | (map_x < 0)
    got = values.copy()
    weight = mask_strip(got, map_x, map_y, quality, 0.4, np.packbits(occluded, axis=1), 30)
    np.testing.assert_array_equal(np.isnan(got), bad)
    np.testing.assert_array_equal(weight, np.where(bad, 0, quality))
    got = values.copy()   # no occluder mask: only invisible, missing and poor nodes
    mask_strip(got, map_x, map_y, quality, 0.4, np.zeros((0, 0), np.uint8), 0)
    np.testing.assert_array_equal(np.isnan(got),
                                  (map_x < 0) | ~np.isfinite(values) | (quality < 0.4))


def test_local_contrast_is_value_over_local_mean() -> None:
    values = (0.5 + RNG.random((40, 50))).astype(np.float32)
    values[5:9, 10:20] = np.nan
    contrast, support = local_contrast(values, 3.0)
    valid = np.isfinite(values)
    filled = np.where(valid, values, 0).astype(np.float32)
    # the compiled contrast is the expression on the blurs exactly; the blurs are
    # OpenCV's GaussianBlur to float32 rounding (pipestitch.imaging)
    for blur_of, tol in ((lambda a: gaussian_blur(a, 3.0, border=cv2.BORDER_REFLECT), 0.0),
                         (lambda a: cv2.GaussianBlur(a, (0, 0), 3.0,
                                                     borderType=cv2.BORDER_REFLECT), 2e-6)):
        blur = [blur_of(a) for a in (valid.astype(np.float32), filled)]
        local = blur[1] / np.maximum(blur[0], np.float32(1e-6))
        want = np.where(valid, filled / np.maximum(local, np.float32(1e-6)) - 1, 0)
        np.testing.assert_allclose(contrast, want.astype(np.float32), rtol=0, atol=tol)
        np.testing.assert_allclose(support, blur[0], rtol=0, atol=tol)
