"""The compiled unwrapping kernels against the numpy/OpenCV expressions they replace
(written out again here).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.camera import CameraModel, default_camera
from pipestitch.camera.opencv_fisheye import OpenCVFisheyeModel
from pipestitch.geometry import PipeSection, Pose, RadiusProfile, WallGrid
from pipestitch.imaging import gaussian_blur
from pipestitch.mosaic._unwrap_kernels import (
    MapFields,
    mask_strip,
    upsample_maps,
)
from pipestitch.mosaic.unwrap import _node_fields, local_contrast

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


def _rows_then_columns(nodes: np.ndarray, step: int, n_rows: int, n_cols: int) -> np.ndarray:
    """The float32 interpolation written out: rows first, then columns, weights k / step
    rounded to float32, a copy on the nodes and past the last one."""
    w_hi = np.array([k / step for k in range(step)], np.float32)
    w_lo = np.float32(1) - w_hi

    def along(a: np.ndarray, n: int, axis: int) -> np.ndarray:
        a = np.moveaxis(a, axis, 0)
        out = np.empty((n,) + a.shape[1:], np.float32)
        for i in range(n):
            c, k = min(i // step, len(a) - 1), i % step
            out[i] = a[c] if k == 0 or c == len(a) - 1 else a[c] * w_lo[k] + a[c + 1] * w_hi[k]
        return np.moveaxis(out, 0, axis)

    return along(along(nodes, n_rows, 1), n_cols, 2)


@pytest.mark.parametrize("step", [1, 2, 3, 4, 5, 8])
@pytest.mark.parametrize("cut", [0, 1, 2, 5])
def test_upsampled_fields_are_the_float32_expression_to_the_bit(step: int, cut: int) -> None:
    # ``cut`` output columns short of the last node: a last cell with only some phases.
    n_r, n_c = 7, 9
    n_rows, n_cols = n_r * step + 2, max(1, (n_c - 1) * step + 1 - cut)
    nodes = (RNG.normal(size=(5, n_r, n_c)) * 100).astype(np.float32)
    nodes[2] = 1.0
    nodes[2, 3, 4] = 0.0
    out = upsample_maps(MapFields(*nodes), step=step, n_rows=n_rows, n_cols=n_cols,
                        ok_above=0.999)
    want = _rows_then_columns(nodes, step, n_rows, n_cols)
    ok = want[2] > np.float32(0.999)
    for name, k in (("map_x", 0), ("map_y", 1), ("quality", 3), ("shading", 4)):
        fill = -1.0 if k < 2 else 0.0
        np.testing.assert_array_equal(getattr(out, name), np.where(ok, want[k], fill))


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


def _node_fields_numpy(camera: CameraModel, pose: Pose, section: PipeSection, grid: WallGrid,
                       step: int, profile: RadiusProfile | None) -> MapFields:
    """The nodes' fields as numpy expressions: every node's wall point, its pixel, the
    gradients of the pixels over the node grid and the line of sight."""
    local = Pose(pose.alpha, pose.beta, pose.dx_mm, pose.dy_mm)
    n_r = -(-(grid.n_rows - 1) // step) + 1
    n_c = -(-(grid.n_cols - 1) // step) + 1
    theta = np.deg2rad(grid.theta0_deg + np.arange(n_r) * step * grid.deg_per_px)
    z = grid.z0_mm + np.arange(n_c) * step * grid.mm_per_px_axial
    ring = section.points(theta, np.zeros_like(theta))
    axis, seen = local.rotation_world_probe()[2], local.to_probe(ring)
    scale = np.ones_like(z) if profile is None else profile.at(z)
    if profile is None:
        probe = seen[:, None, :] + z[None, :, None] * axis
    else:
        origin = local.to_probe(np.zeros((1, 3)))
        probe = (origin + scale[None, :, None] * (seen - origin)[:, None, :]
                 + z[None, :, None] * axis)
    px = camera.project(probe.reshape(-1, 3)).reshape(n_r, n_c, 2)
    valid = np.isfinite(px).all(axis=2)
    px = np.where(valid[..., None], px, 0.0)
    centre, normals = local.translation_world_probe(), section.normals(ring)
    radial = np.sum(ring * normals, axis=1)[:, None] * scale[None, :]
    along_normal = np.abs(radial - (normals[:, :2] @ centre[:2])[:, None])
    across = ((ring[:, None, 0] * scale - centre[0]) ** 2
              + (ring[:, None, 1] * scale - centre[1]) ** 2)
    distance = np.sqrt(across + (z - centre[2])[None, :] ** 2)
    cosine = np.clip(along_normal / distance, 0, 1)
    resolution = np.minimum(*(np.hypot(np.gradient(px[..., 0], axis=a),
                                       np.gradient(px[..., 1], axis=a)) for a in (0, 1)))
    return MapFields(px[..., 0], px[..., 1], valid.astype(float), resolution / step * cosine,
                     cosine * (grid.radius_mm / distance) ** 2)


@pytest.mark.parametrize("lens", ["ocam", "opencv_fisheye"])
def test_node_fields_are_the_numpy_expressions(lens: str) -> None:
    camera = default_camera("half") if lens == "ocam" else OpenCVFisheyeModel(
        330.0, 331.0, 611.0, 515.0, (0.02, -0.01, 0.003, -0.0005), 1224, 1024)
    rng = np.random.default_rng(3)
    unseen = 0
    for case in range(12):
        pose = Pose(*np.deg2rad(rng.uniform(-4, 4, 2)), *rng.uniform(-8, 8, 2))
        section = (PipeSection(32.5) if case % 2 else
                   PipeSection(32.5, 32.5 * rng.uniform(0.95, 1.05), rng.uniform(0, np.pi)))
        z_knots = np.linspace(-30.0, 70.0, 9)
        profile = (None if case % 3 == 0 else
                   RadiusProfile(z_knots, 1 + 0.05 * np.sin(z_knots / 10 + case)))
        grid = WallGrid.window(32.5, float(rng.choice([0.13, 0.27, 0.53])),
                               rng.uniform(-80, 0), rng.uniform(5, 60))
        step = int(rng.choice([1, 4, 16]))
        want = _node_fields_numpy(camera, pose, section, grid, step, profile)
        got, z = _node_fields(camera, pose, section, grid, step, True, profile)
        assert z.shape == want.map_x.shape[1:]
        assert np.count_nonzero(want.valid) > 0
        unseen += np.count_nonzero(want.valid == 0)
        for name in MapFields._fields:   # the same operations in the same order: equal
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name),
                                          err_msg=f"{name}, case {case}")
        maps_only, _ = _node_fields(camera, pose, section, grid, step, False, profile)
        assert maps_only.quality is None and maps_only.shading is None
        np.testing.assert_array_equal(maps_only.map_x, want.map_x)
        np.testing.assert_array_equal(maps_only.valid, want.valid)
    assert unseen > 0   # nodes behind the lens' field of view were among them
