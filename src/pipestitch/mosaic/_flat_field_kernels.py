"""Compiled inner loops of the flat field (numba): the fall-off at every strip node,
every node's ring of image radius, the node pairs of two overlapping strips and the
medians of groups of values.

Why hand-written: numpy needs five temporary arrays of the strip's size for the radius,
the ring position, its whole and fractional parts and the interpolation; this is one
pass (a stitch strip is about a million nodes). An overlap's node pairs took a dozen
numpy calls on sampled strips and a sort of all of them by group (~0.6 ms an overlap,
~400 overlaps in 200 pairs, most of it holding the interpreter between calls); here
one pass pairs them, a counting sort groups them and each group's median is selected
alone.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

F32 = np.float32


@numba.njit(cache=True, nogil=True)
def fall_off_at(map_x: np.ndarray, map_y: np.ndarray, centre_col: float, centre_row: float,
                ring_px: float, level: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``level`` (per ring centre, rings ``ring_px`` wide from the centre) interpolated
    linearly at the radius of every pixel position, the end rings' values beyond them
    (float32, the maps' shape); multiplied by ``times`` (float32, the maps' shape; empty:
    not) as float32 arrays multiply.

    Row by row: the ring positions first (a loop the compiler vectorises), then the
    look-ups (2x faster than both in one loop; the same values).
    """
    n = level.shape[0]
    out = np.empty(map_x.shape, np.float32)
    pos = np.empty(map_x.shape[1])
    scaled = times.size > 0
    for i in range(map_x.shape[0]):
        _ring_positions(map_x[i], map_y[i], centre_col, centre_row, ring_px, n - 1.0, pos)
        row = out[i]
        for j in range(map_x.shape[1]):
            low = min(int(pos[j]), n - 2)
            frac = pos[j] - low
            row[j] = F32(level[low] * (1.0 - frac) + level[low + 1] * frac)
        if scaled:
            for j in range(map_x.shape[1]):
                row[j] = times[i, j] * row[j]
    return out


@numba.njit(cache=True, nogil=True)
def _ring_positions(map_x: np.ndarray, map_y: np.ndarray, centre_col: float,
                    centre_row: float, ring_px: float, last: float, pos: np.ndarray) -> None:
    """Each position's distance from the centre in rings, less half a ring, clipped to
    [0, ``last``] (float64)."""
    for j in range(map_x.shape[0]):
        dx = np.float64(map_x[j]) - centre_col
        dy = np.float64(map_y[j]) - centre_row
        pos[j] = min(max(np.sqrt(dx * dx + dy * dy) / ring_px - 0.5, 0.0), last)


@numba.njit(cache=True, nogil=True)
def ring_index(map_x: np.ndarray, map_y: np.ndarray, centre_col: float, centre_row: float,
               rings_per_px: float, n_rings: int) -> np.ndarray:
    """The ring of image radius of every pixel position (int16, -1 beyond the last ring):
    ``int32(radius · rings_per_px)`` in float32, the radius ``hypot`` of the float32
    offsets from the centre in float64, rounded once to float32 (C's ``hypotf``)."""
    out = np.empty(map_x.shape, np.int16)
    cx, cy, k = F32(centre_col), F32(centre_row), F32(rings_per_px)
    for i in range(map_x.shape[0]):
        for j in range(map_x.shape[1]):
            dx, dy = np.float64(map_x[i, j] - cx), np.float64(map_y[i, j] - cy)
            ring = np.int32(F32(np.sqrt(dx * dx + dy * dy)) * k)
            out[i, j] = ring if 0 <= ring < n_rings else -1
    return out


@numba.njit(cache=True, nogil=True)
def pair_cells(first_ring: np.ndarray, first_log: np.ndarray, second_ring: np.ndarray,
               second_log: np.ndarray, dr: int, dc: int,
               n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """The node pairs of two strips on one grid, the second moved by (``dr``, ``dc``)
    nodes (rows wrapping around): every 4th row and 2nd column of the second (from its
    first row and from column ``max(0, -dc)``) with node (r + dr, c + dc) of the first.

    Returns each pair's cell ``first ring * n_bins + second ring`` (int64) and its
    ``second_log - first_log`` (float32), in row-major order of the second's nodes,
    where both rings are >= 0 and the difference is finite.
    """
    n_rows, n_cols = second_ring.shape
    c_lo, c_hi = max(0, -dc), min(n_cols, n_cols - dc)
    size = ((n_rows + 3) // 4) * max(0, (c_hi - c_lo + 1) // 2)
    cell = np.empty(size, np.int64)
    y = np.empty(size, np.float32)
    k = 0
    for r2 in range(0, n_rows, 4):
        r1 = (r2 + dr) % n_rows
        for c2 in range(c_lo, c_hi, 2):
            a, b = first_ring[r1, c2 + dc], second_ring[r2, c2]
            v = second_log[r2, c2] - first_log[r1, c2 + dc]
            if a >= 0 and b >= 0 and np.isfinite(v):
                cell[k], y[k] = np.int64(a) * n_bins + b, v
                k += 1
    return cell[:k], y[:k]


@numba.njit(cache=True, nogil=True)
def group_medians(group: np.ndarray, value: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each group present (ascending), its size and its median: the upper middle one of
    its values in order (``value[count // 2]`` sorted; ±inf sort to the ends).
    ``group``: non-negative int64; ``value``: float32 without NaN."""
    n_groups = group.max() + 1 if group.size else 0
    start = np.zeros(n_groups + 1, np.int64)
    for g in group:
        start[g + 1] += 1
    present = 0
    for g in range(n_groups):
        present += start[g + 1] > 0
        start[g + 1] += start[g]
    ordered = np.empty(value.size, value.dtype)
    filled = start[:-1].copy()
    for i in range(group.size):   # a counting sort by group, each group's values in order
        ordered[filled[group[i]]] = value[i]
        filled[group[i]] += 1
    groups = np.empty(present, np.int64)
    counts = np.empty(present, np.int64)
    medians = np.empty(present, value.dtype)
    k = 0
    for g in range(n_groups):
        count = start[g + 1] - start[g]
        if count:
            medians[k] = _kth_smallest(ordered[start[g]:start[g + 1]], count // 2)
            groups[k], counts[k] = g, count
            k += 1
    return groups, counts, medians


@numba.njit(cache=True, nogil=True)
def _kth_smallest(values: np.ndarray, k: int) -> float:
    """The ``k``-th smallest of ``values`` (no NaN), which it reorders: Hoare's
    selection (each pass splits about the median of the ends and the middle, and goes
    on in the part holding ``k``), ~3 passes over the values instead of a sort. For the
    cells' few dozen values each: the package's radix selection
    (:func:`pipestitch.imaging.medians.median`, for a frame's many thousands) counts
    2048 digits a pass and took twice as long over an overlap's ~300 cells."""
    lo, hi = 0, values.size - 1
    while lo < hi:
        a, b, c = values[lo], values[(lo + hi) // 2], values[hi]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:   # between the two parts: equal to the pivot
            return values[k]
    return values[k]
