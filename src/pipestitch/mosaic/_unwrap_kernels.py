"""Compiled inner loops of unwrapping (numba): the maps' nodes and their fields,
upsampled maps, strip masks, local contrast.

Why hand-written: every LED frame is unwrapped once or twice per run and each strip
(about a million nodes at full size) then goes through a dozen whole-array passes; as
numpy expressions each pass allocates and walks the array again and most of the time
goes to memory traffic. OpenCV's resize/remap quantise interpolation weights to 1/32
(see :func:`pipestitch.mosaic.unwrap.unwrap_maps`), so they cannot stand in. The
nodes' fields (some ten thousand nodes a strip, four or five maps a frame) took ~25
small array expressions, whose overhead, with the GIL held, cost as much as the
projection they surround.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled
kernels". :func:`upsample_maps` is the one plain-Python wrapper: it names the fields
:func:`upsample_masked` takes and gives as a stack.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def _interp_line(src: np.ndarray, step: int, w_lo: np.ndarray, w_hi: np.ndarray,
                 dst: np.ndarray) -> None:
    """``dst[c·step + k] = src[c]·w_lo[k] + src[c + 1]·w_hi[k]`` (``src[c]`` for k = 0).

    Phase by phase (each k a counted loop over the whole cells, which the compiler
    vectorises; ~40 % faster than cell by cell), then the last, partial cell.
    """
    n, last = dst.shape[0], src.shape[0] - 1
    whole = min(last, n // step)   # cells whose every phase lies in dst
    for c in range(min(last + 1, (n + step - 1) // step)):
        dst[c * step] = src[c]
    for k in range(1, step):
        lo, hi = w_lo[k], w_hi[k]
        for c in range(whole):
            dst[c * step + k] = src[c] * lo + src[c + 1] * hi
    if whole < last:
        base = whole * step
        for k in range(1, min(step, n - base)):
            dst[base + k] = src[whole] * w_lo[k] + src[whole + 1] * w_hi[k]


@numba.njit(cache=True, nogil=True)
def upsample_masked(nodes: np.ndarray, step: int, n_rows: int, n_cols: int,
                    ok_above: float) -> np.ndarray:
    """Bilinear upsampling of node fields, masked where the validity field is not ~1.

    ``nodes`` (F, rows, cols) float32 every ``step`` nodes (the last row/column is
    the last node); field 2 is the validity (1/0). Returns (F - 1, n_rows, n_cols)
    float32: fields 0 and 1 (map x, y) with -1 and the fields after the validity with
    0 where the interpolated validity is not above ``ok_above``. Rows first, then
    columns, with the weights (k / step as float32) of the numpy original; a node
    that falls on a grid node is copied (the original's ``a·1 + b·0``: the same for
    finite values).
    """
    n_f, last_r = nodes.shape[0], nodes.shape[1] - 1
    out = np.empty((n_f - 1, n_rows, n_cols), np.float32)
    w_hi = np.empty(step, np.float32)
    w_lo = np.empty(step, np.float32)
    for k in range(step):
        w_hi[k] = F32(k / step)
        w_lo[k] = F32(1) - w_hi[k]
    row = np.empty(nodes.shape[2], np.float32)
    valid = np.empty(n_cols, np.float32)
    ok_f = F32(ok_above)
    for i in range(n_rows):
        r0, k = min(i // step, last_r), i % step
        for order in range(n_f):   # the validity first: it masks the others
            f = 2 if order == 0 else (order - 1 if order <= 2 else order)
            if k == 0 or r0 == last_r:
                for c in range(row.shape[0]):   # not a slice assignment: less to compile
                    row[c] = nodes[f, r0, c]
            else:
                for c in range(row.shape[0]):
                    row[c] = nodes[f, r0, c] * w_lo[k] + nodes[f, r0 + 1, c] * w_hi[k]
            if f == 2:
                _interp_line(row, step, w_lo, w_hi, valid)
                continue
            dst = out[f if f < 2 else f - 1, i]
            _interp_line(row, step, w_lo, w_hi, dst)
            fill = F32(-1) if f < 2 else F32(0)
            for j in range(n_cols):
                if not valid[j] > ok_f:
                    dst[j] = fill
    return out


@numba.njit(cache=True, nogil=True)
def node_points(seen: np.ndarray, z: np.ndarray, axis: np.ndarray, origin: np.ndarray,
                scale: np.ndarray) -> np.ndarray:
    """Probe-frame points of a strip's nodes, (rows · cols, 3), row after row.

    ``seen`` (rows, 3) is the ring of wall points at z = 0 in the probe frame, ``z``
    (cols,) the columns' axial positions, ``axis`` the pipe axis seen from the probe.
    Node (r, c) is ``seen[r] + z[c]·axis``; with a ``scale`` (cols,; empty: none) the
    ring is first scaled about the pipe axis' point ``origin``: ``origin + scale[c]·
    (seen[r] − origin) + z[c]·axis`` (the numpy broadcast's sums in its order).
    """
    rows, cols = seen.shape[0], z.shape[0]
    out = np.empty((rows * cols, 3))
    scaled = scale.shape[0] > 0
    for r in range(rows):
        for c in range(cols):
            for k in range(3):
                wall = (origin[k] + scale[c] * (seen[r, k] - origin[k]) if scaled
                        else seen[r, k])
                out[r * cols + c, k] = wall + z[c] * axis[k]
    return out


@numba.njit(cache=True, nogil=True)
def node_fields(px: np.ndarray, rows: int, cols: int, step: int, with_quality: bool,
                sight: np.ndarray, ring_xy: np.ndarray, scale: np.ndarray, z: np.ndarray,
                centre: np.ndarray, radius: float) -> np.ndarray:
    """A strip's node fields from the nodes' pixels ``px`` (rows · cols, 2): (F, rows,
    cols) float64 of map x, map y (0 where not seen), validity (1/0) and, with
    ``with_quality``, the quality and the shading of
    :class:`pipestitch.mosaic.unwrap.UnwrapMaps`.

    Quality: source pixels per node step (the smaller of the two grid directions'
    central differences, one-sided at the edges: ``numpy.gradient``'s), divided by
    ``step`` and times the cosine of the line of sight on the wall, clipped to [0, 1].
    The wall point of node (r, c) is ``ring_xy[r]`` scaled by ``scale[c]`` at ``z[c]``;
    ``sight[0, r]`` is its radial distance along the wall normal at scale 1 and
    ``sight[1, r]`` the normal's dot product with the camera centre ``centre``.
    Shading: the cosine times (``radius`` / distance)². A direction with a single node
    does not count for the quality; with neither, it is 0.
    """
    out = np.zeros((5 if with_quality else 3, rows, cols))
    for r in range(rows):
        for c in range(cols):
            x, y = px[r * cols + c, 0], px[r * cols + c, 1]
            if np.isfinite(x) and np.isfinite(y):
                out[0, r, c], out[1, r, c], out[2, r, c] = x, y, 1.0
    if not with_quality:
        return out
    for r in range(rows):
        for c in range(cols):
            across = ((ring_xy[r, 0] * scale[c] - centre[0]) ** 2
                      + (ring_xy[r, 1] * scale[c] - centre[1]) ** 2)
            distance = np.sqrt(across + (z[c] - centre[2]) ** 2)
            cosine = min(max(abs(sight[0, r] * scale[c] - sight[1, r]) / distance, 0.0), 1.0)
            down = along = np.inf
            if rows > 1:
                down = math.hypot(_derivative(out[0, :, c], r), _derivative(out[1, :, c], r))
            if cols > 1:
                along = math.hypot(_derivative(out[0, r], c), _derivative(out[1, r], c))
            res = min(down, along)
            out[3, r, c] = (res if res < np.inf else 0.0) / step * cosine
            out[4, r, c] = cosine * (radius / distance) ** 2
    return out


@numba.njit(cache=True, nogil=True)
def _derivative(f: np.ndarray, i: int) -> float:
    """``numpy.gradient(f)[i]`` at unit spacing (central inside, one-sided at the ends)."""
    if i == 0:
        return (f[1] - f[0]) / 1.0
    if i == f.shape[0] - 1:
        return (f[i] - f[i - 1]) / 1.0
    return (f[i + 1] - f[i - 1]) / 2.0


class MapFields(NamedTuple):
    """The fields of a strip's maps, each (rows, cols): the pixel column and row where
    every node is seen, whether it is seen (``valid``, 1/0) and, when computed, its
    quality and shading (see :class:`pipestitch.mosaic.unwrap.UnwrapMaps`); None where
    absent."""

    map_x: np.ndarray
    map_y: np.ndarray
    valid: np.ndarray | None = None
    quality: np.ndarray | None = None
    shading: np.ndarray | None = None


def upsample_maps(nodes: MapFields, *, step: int, n_rows: int, n_cols: int,
                  ok_above: float) -> MapFields:
    """:func:`upsample_masked` of named fields (the same float32 values).

    ``nodes``: the fields every ``step`` nodes, ``valid`` included. Returns the fields
    on the (``n_rows``, ``n_cols``) grid, masked where the interpolated validity is not
    above ``ok_above`` (map -1, others 0); ``valid`` is None there (it is the mask),
    and fields absent from ``nodes`` stay None.
    """
    names = [name for name, field in zip(MapFields._fields, nodes, strict=True)
             if field is not None]
    if names[:3] != ["map_x", "map_y", "valid"]:
        raise ValueError(f"upsample_maps: the nodes need map_x, map_y and valid, got {names}")
    # cast while stacked: one pass (a float64 stack cast afterwards took 2-3 times as long)
    stack = np.stack([field for field in nodes if field is not None], dtype=np.float32)
    out = upsample_masked(stack, step, n_rows, n_cols, ok_above)
    names.remove("valid")
    return MapFields(**dict(zip(names, out, strict=True)))


@numba.njit(cache=True, nogil=True)
def mask_strip(values: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, quality: np.ndarray,
               min_quality: float, occluded_bits: np.ndarray, width: int) -> np.ndarray:
    """Mask a remapped strip in place and return its weight (``quality``, 0 where masked).

    A node is masked (NaN) where ``map_x`` < 0 (invisible), the value is not finite
    (outside the frame), ``quality`` < ``min_quality`` (float32 comparison) or the
    frame pixel nearest to it (rounded half to even, as ``cv2.remap`` with
    ``INTER_NEAREST`` does) is occluded or outside the frame. ``occluded_bits`` is the
    occluder mask of a frame ``width`` pixels wide packed eight pixels to a byte along
    its rows (``numpy.packbits(mask, axis=1)``: a 1224 x 1024 mask in 157 kB, which the
    cache holds better while a strip's rays read it in their scattered order: in a
    60-pair run the test took 0.16 s of CPU on the 1.2 MB mask, 0.10 s packed); an
    empty one skips that last test.
    """
    weight = np.empty(values.shape, np.float32)
    q_min = F32(min_quality)
    check = occluded_bits.size > 0
    height = occluded_bits.shape[0]
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            bad = map_x[i, j] < 0 or not np.isfinite(values[i, j]) or quality[i, j] < q_min
            if check and not bad:
                col, row = int(np.rint(map_x[i, j])), int(np.rint(map_y[i, j]))
                bad = not (0 <= col < width and 0 <= row < height) or (
                    (occluded_bits[row, col >> 3] >> (7 - (col & 7))) & 1) == 1
            if bad:
                values[i, j] = np.nan
                weight[i, j] = F32(0)
            else:
                weight[i, j] = quality[i, j]
    return weight


@numba.njit(cache=True, nogil=True)
def fill_invalid(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` with non-finite nodes set to 0, and the validity (1/0), both float32."""
    filled = np.empty(values.shape, np.float32)
    valid = np.empty(values.shape, np.float32)
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            ok = np.isfinite(values[i, j])
            filled[i, j] = values[i, j] if ok else F32(0)
            valid[i, j] = F32(1) if ok else F32(0)
    return filled, valid


@numba.njit(cache=True, nogil=True)
def contrast_of(filled: np.ndarray, valid: np.ndarray, support: np.ndarray,
                local: np.ndarray) -> np.ndarray:
    """value / local mean - 1 where valid (0 elsewhere); ``local`` is divided by the
    ``support`` (blurred validity) in place, making it the local mean. float32."""
    out = np.empty(filled.shape, np.float32)
    tiny = F32(1e-6)
    for i in range(filled.shape[0]):
        for j in range(filled.shape[1]):
            local[i, j] = local[i, j] / max(support[i, j], tiny)
            out[i, j] = filled[i, j] / max(local[i, j], tiny) - F32(1) if valid[i, j] else F32(0)
    return out
