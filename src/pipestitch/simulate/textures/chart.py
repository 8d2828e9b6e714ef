"""The high-contrast test chart, laid out in millimetres on the wall.

Cells of 10 mm with a frame, a label and one of seven patterns, every edge
box-filtered analytically at the grid's pixel size, so the chart looks the same at
any resolution (see :func:`chart_texture`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from pipestitch.geometry import WallGrid
from pipestitch.simulate.textures._texture_common import as_rng, ramp_width

__all__ = ["chart_texture"]

_CHART_CELL_MM = 10.0        # chart cell pitch along z (around: adjusted to fit the turn)
_CHART_BLACK = 0.05
_CHART_WHITE = 0.92
_CHART_MARGIN_MM = 0.5       # free border inside each cell
_CHART_LINE_MM = 0.15        # cell frame line width
_LABEL_H_MM = 1.3            # label box height
_LABEL_CAP_MM = 0.75         # label text height
_LABEL_STROKE_MM = 0.09      # label text stroke width
_LABEL_PX_PER_MM = 40.0      # resolution at which label text is rasterised
_PITCHES_MM = (0.2, 0.4, 0.8, 1.6)
_N_CHART_PATTERNS = 7


def _box_wave(x: np.ndarray, period: float, duty: float, width: float | np.ndarray) -> np.ndarray:
    """Box-filtered square wave.

    The fraction of ``[x - width/2, x + width/2]`` where ``x mod period < duty``
    (exact, through the wave's antiderivative), i.e. a pixel of ``width`` mm
    integrating stripes of ``duty`` mm every ``period`` mm; no aliasing.
    """
    def prim(t: np.ndarray) -> np.ndarray:
        q = np.floor(t / period)
        return q * duty + np.minimum(t - q * period, duty)

    half = 0.5 * np.asarray(width)
    return (prim(x + half) - prim(x - half)) / (2.0 * half)


def _box_interval(x: np.ndarray, a: float, b: float, width: float) -> np.ndarray:
    """Fraction of the pixel ``[x - width/2, x + width/2]`` inside ``[a, b]``."""
    half = 0.5 * width
    return np.clip(np.minimum(x + half, b) - np.maximum(x - half, a), 0.0, None) / width


def _render_label(text: str, max_width_mm: float) -> tuple[np.ndarray, float]:
    """Rasterise a label (ink 0..1) at ``_LABEL_PX_PER_MM``; returns (image, width_mm)."""
    r0 = _LABEL_PX_PER_MM
    font = cv2.FONT_HERSHEY_SIMPLEX
    thick = max(1, round(_LABEL_STROKE_MM * r0))
    (_, h1), _ = cv2.getTextSize("0", font, 1.0, thick)
    scale = _LABEL_CAP_MM * r0 / h1
    (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
    pad = round(0.2 * r0)
    if tw + 2 * pad > max_width_mm * r0:
        scale *= max(0.2, (max_width_mm * r0 - 2 * pad) / tw)
        (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
    height = round(_LABEL_H_MM * r0)
    width = tw + 2 * pad
    canvas = np.zeros((height, width), np.uint8)
    cv2.putText(canvas, text, (pad, (height + th) // 2), font, scale, 255, thick, cv2.LINE_AA)
    return canvas.astype(np.float32) / 255.0, width / r0


def _paste_label(ink: np.ndarray, u: np.ndarray, v: np.ndarray, u0: float, v0: float,
                 label: np.ndarray, width_mm: float, ws: float, wz: float) -> None:
    """Put a label box (paper with text) into a cell's ink block at (u0, v0) mm."""
    h_mm = _LABEL_H_MM
    i0, i1 = np.searchsorted(u, [u0 - ws, u0 + h_mm + ws])
    j0, j1 = np.searchsorted(v, [v0 - wz, v0 + width_mm + wz])
    if i1 <= i0 or j1 <= j0:
        return
    img = label
    # Area-prefilter down to ~2 samples per grid pixel before the exact warp.
    rows_t = max(1, round(2 * h_mm / ws))
    cols_t = max(1, round(2 * width_mm / wz))
    if rows_t < img.shape[0] or cols_t < img.shape[1]:
        img = cv2.resize(img, (min(cols_t, img.shape[1]), min(rows_t, img.shape[0])),
                         interpolation=cv2.INTER_AREA)
    rs = img.shape[0] / h_mm
    rz = img.shape[1] / width_mm
    m = np.array([[wz * rz, 0.0, (v[j0] - v0) * rz - 0.5],
                  [0.0, ws * rs, (u[i0] - u0) * rs - 0.5]])
    text = cv2.warpAffine(img, m, (int(j1 - j0), int(i1 - i0)),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    box = (_box_interval(u[i0:i1], u0, u0 + h_mm, ws)[:, None]
           * _box_interval(v[j0:j1], v0, v0 + width_mm, wz)[None, :])
    blk = ink[i0:i1, j0:j1]
    blk *= 1.0 - box
    blk += text * box


def _disc_ink(du: np.ndarray, dv: np.ndarray, radius: float, ring: float | None, ws: float,
              wz: float) -> np.ndarray:
    """Antialiased disc (``ring=None``) or ring of width ``ring`` (mm), from offsets (mm)."""
    dist = np.hypot(du, dv)
    w = ramp_width(du, dv, dist, ws, wz)
    d = dist - radius if ring is None else np.abs(dist - radius) - 0.5 * ring
    return np.clip(0.5 - d / w, 0.0, 1.0)


def _cell_pattern(kind: int, crng: np.random.Generator, u: np.ndarray, v: np.ndarray,
                  ua: float, ub: float, va: float, vb: float, ws: float, wz: float) -> np.ndarray:
    """Ink (0..1) of one chart pattern over a cell block, inside [ua, ub] x [va, vb] mm."""
    ru = _box_interval(u, ua, ub, ws)
    rv = _box_interval(v, va, vb, wz)
    p = float(crng.choice(_PITCHES_MM))
    if kind == 0:      # stripes across the axis (varying along z)
        return ru[:, None] * (rv * _box_wave(v - va, p, p / 2, wz))[None, :]
    if kind == 1:      # stripes along the axis (varying around)
        return (ru * _box_wave(u - ua, p, p / 2, ws))[:, None] * rv[None, :]
    if kind == 2:      # checkerboard (exact box filter of the XOR of two square waves)
        p = float(crng.choice((0.25, 0.5, 1.0, 2.0)))
        qu = _box_wave(u - ua, 2 * p, p, ws)[:, None]
        qv = _box_wave(v - va, 2 * p, p, wz)[None, :]
        return (qu + qv - 2.0 * qu * qv) * ru[:, None] * rv[None, :]
    if kind == 3:      # scattered discs and rings
        ink = np.zeros((len(u), len(v)), np.float32)
        for _ in range(int(crng.integers(5, 11))):
            r = float(crng.uniform(0.3, 1.8))
            ring = None if crng.random() < 0.5 else float(crng.uniform(0.2, 0.4))
            cu = float(crng.uniform(ua + r, max(ua + r, ub - r)))
            cv = float(crng.uniform(va + r, max(va + r, vb - r)))
            ext = r + (ring or 0.0) + max(ws, wz)
            i0, i1 = np.searchsorted(u, [cu - ext, cu + ext])
            j0, j1 = np.searchsorted(v, [cv - ext, cv + ext])
            if i1 > i0 and j1 > j0:
                d = _disc_ink(u[i0:i1, None] - cu, v[None, j0:j1] - cv, r, ring, ws, wz)
                np.maximum(ink[i0:i1, j0:j1], d, out=ink[i0:i1, j0:j1])
        return ink * ru[:, None] * rv[None, :]
    if kind == 4:      # bullseye: concentric rings
        cu, cv = 0.5 * (ua + ub), 0.5 * (va + vb)
        rmax = 0.5 * min(ub - ua, vb - va)
        du = u[:, None] - cu
        dv = v[None, :] - cv
        dist = np.hypot(du, dv)
        w = ramp_width(du, dv, dist, ws, wz)
        p = max(p, 0.4)
        return _box_wave(dist, p, p / 2, w) * np.clip(0.5 - (dist - rmax) / w, 0.0, 1.0)
    if kind == 5:      # oblique stripes
        phi = math.radians(float(crng.uniform(20.0, 70.0)) * float(crng.choice((-1.0, 1.0))))
        c, s = math.cos(phi), math.sin(phi)
        x = (u[:, None] - ua) * c + (v[None, :] - va) * s
        w = math.hypot(c * ws, s * wz)
        return _box_wave(x, p, p / 2, w) * ru[:, None] * rv[None, :]
    # kind 6: a calibrated corner: millimetre rulers along z (top) and around (left),
    # and a 1 mm checkerboard in the rest.
    tw = 0.1
    ticks = ((0.5, 0.8), (1.0, 1.3), (5.0, 2.0))
    ink = np.zeros((len(u), len(v)), np.float32)
    v_tick = v - va + tw / 2
    u_tick = u - ua + tw / 2
    for period, length in ticks:
        tz = _box_wave(v_tick, period, tw, wz) * rv
        np.maximum(ink, _box_interval(u, ua, ua + length, ws)[:, None] * tz[None, :], out=ink)
        ts = _box_wave(u_tick, period, tw, ws) * ru
        np.maximum(ink, ts[:, None] * _box_interval(v, va, va + length, wz)[None, :], out=ink)
    np.maximum(ink, _box_interval(u, ua, ua + tw, ws)[:, None] * rv[None, :], out=ink)
    np.maximum(ink, ru[:, None] * _box_interval(v, va, va + tw, wz)[None, :], out=ink)
    ca, cb = ua + 2.4, va + 2.4
    if ub - ca > 1.0 and vb - cb > 1.0:
        qu = _box_wave(u - ca, 2.0, 1.0, ws)[:, None]
        qv = _box_wave(v - cb, 2.0, 1.0, wz)[None, :]
        box = (_box_interval(u, ca, ub, ws)[:, None] * _box_interval(v, cb, vb, wz)[None, :])
        np.maximum(ink, (qu + qv - 2.0 * qu * qv) * box, out=ink)
    return ink


def chart_texture(grid: WallGrid, rng: np.random.Generator | int) -> np.ndarray:
    """High-contrast test chart, laid out in millimetres on the wall.

    The wall is divided into cells of 10 mm along z (aligned to absolute z = 0)
    and about 10 mm of arc around (an integer number per turn, so the chart closes
    seamlessly). Each cell has a thin black frame, a label ``"z<Z> a<A>"`` (z of
    the cell start in mm, its angle in degrees; text drawn with
    :func:`cv2.putText`) and one randomly chosen pattern: stripes across or along
    the axis or oblique (pitch 0.2-1.6 mm), a checkerboard (0.25-2 mm squares),
    scattered discs and rings (0.6-3.6 mm), a bullseye, or a calibrated corner
    (millimetre rulers along z and around, and a 1 mm checkerboard). All edges are
    box-filtered analytically at the grid's pixel size, so the chart looks the same
    (up to sampling) at any resolution and fine patterns fade to grey rather than
    alias. The cell contents depend only on the
    radius, the absolute cell position and one number drawn from ``rng``: two
    grids of the same pipe rendered with equal generator states agree where they
    overlap.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source (one draw).

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo, black 0.05 and white 0.92.
    """
    rng = as_rng(rng)
    seed = int(rng.integers(0, 2**63 - 1))
    n_rows, n_cols = grid.shape
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    circ = grid.circumference_mm
    n_around = max(1, round(circ / _CHART_CELL_MM))
    hs = circ / n_around
    cell = _CHART_CELL_MM
    s = np.arange(n_rows) * ws
    z = grid.z0_mm + np.arange(n_cols) * wz
    line_s = _box_wave(s, hs, _CHART_LINE_MM, ws).astype(np.float32)
    line_z = _box_wave(z, cell, _CHART_LINE_MM, wz).astype(np.float32)
    row_edges = np.searchsorted(s, np.arange(n_around + 1) * hs - 1e-9 * hs)
    row_edges[-1] = n_rows
    b_first = math.floor((z[0] + 0.5 * wz) / cell) if n_cols else 0
    b_last = math.floor((z[-1] + 0.5 * wz) / cell)
    m = _CHART_MARGIN_MM
    out = np.empty((n_rows, n_cols), np.float32)
    for b in range(b_first, b_last + 1):
        j0, j1 = np.searchsorted(z, [b * cell - 0.5 * wz, (b + 1) * cell - 0.5 * wz])
        if j1 <= j0:
            continue
        v = (z[j0:j1] - b * cell).astype(np.float32)
        for a in range(n_around):
            i0, i1 = int(row_edges[a]), int(row_edges[a + 1])
            if i1 <= i0:
                continue
            u = (s[i0:i1] - a * hs).astype(np.float32)
            crng = np.random.default_rng([seed, a, b + 2**40])
            kind = int(crng.integers(_N_CHART_PATTERNS))
            ua, ub = m + _LABEL_H_MM + 0.4, hs - m
            if ub - ua > 1.0:
                ink = _cell_pattern(kind, crng, u, v, ua, ub, m, cell - m, ws, wz)
            else:
                ink = np.zeros((len(u), len(v)), np.float32)
            np.maximum(ink, line_s[i0:i1, None], out=ink)
            np.maximum(ink, line_z[None, j0:j1], out=ink)
            text = f"z{round(b * cell)} a{round(a * 360 / n_around)}"
            label, width_mm = _render_label(text, cell - 2 * m)
            _paste_label(ink, u, v, m, m, label, width_mm, ws, wz)
            out[i0:i1, j0:j1] = _CHART_WHITE - (_CHART_WHITE - _CHART_BLACK) * ink
    return out
