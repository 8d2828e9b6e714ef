"""Synthetic unrolled pipe-wall textures (albedo images) for the probe simulator.

An *unrolled wall image* stores the wall albedo (reflectance, 0 = black, 1 = white)
on a regular grid in cylinder coordinates (SPEC convention): the centre of pixel
(row ``i``, column ``j``) lies at circumferential angle ``theta = i * deg_per_px``
(degrees, ``[0, 360)``) and axial position ``z = z0_mm + j * mm_per_px_axial``. One
row step is an arc of ``radius_mm * deg2rad(deg_per_px)`` mm on the wall. Rows wrap
around (row ``n_rows`` is row 0 again), and every texture here is seamless across
that wrap.

What it offers

* :class:`WallGrid` - the pixel grid of an unrolled wall and its geometry.
* Four wall textures, all ``float32`` in ``[0, 1]``:
  :func:`chart_texture` (high-contrast test chart, defined in millimetres so it
  looks the same at any resolution), :func:`corrosion_texture` (1/f noise, stains,
  pits), :func:`aluminium_texture` (bright, feature-poor, axially brushed) and
  :func:`photo_texture` (mirror-tiled grey photo).
* :class:`Defect`, :func:`draw_defects` (holes and stains drawn as true circles in
  millimetres on the cylinder, antialiased analytically) and
  :func:`reference_test_piece` (the 7-hole reference cross).
* :func:`make_wall` - texture by name, then defects.

What it does not do: no file I/O, no rendering through a camera, no colour, no
surface relief (holes and pits only change the albedo, not the wall geometry).

Implementation notes. Noise textures are drawn as white noise on a lattice whose
spacing is set in millimetres (about the grid pitch at the finest), shaped by a filter in
the Fourier domain (so they are periodic in theta by construction), composed at
lattice resolution and brought to the grid with one bicubic warp that wraps in
theta. Everything is vectorised; a 65 mm pipe at 0.04 mm/px (~5100 x 6000 px)
takes well under 2 s per texture on 2 cores. Every function is deterministic for a
given :class:`numpy.random.Generator` state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.fft as sfft

__all__ = [
    "DEFECT_KINDS",
    "TEXTURE_KINDS",
    "Defect",
    "WallGrid",
    "aluminium_texture",
    "chart_texture",
    "corrosion_texture",
    "draw_defects",
    "make_wall",
    "photo_texture",
    "reference_test_piece",
]

TEXTURE_KINDS = ("chart", "corrosion", "aluminium", "photo")
DEFECT_KINDS = ("hole", "spot")

HOLE_ALBEDO = 0.02          # albedo inside a hole (almost black)
SPOT_FACTOR = 0.45          # a spot multiplies the albedo by this at its centre
SPOT_SOFT_FRACTION = 0.12   # width of a spot's edge ramp, as a fraction of its diameter

_ROW_CHUNK = 1024           # rows per chunk for full-size element-wise passes


# --------------------------------------------------------------------------- grid


@dataclass(frozen=True)
class WallGrid:
    """Pixel grid of an unrolled pipe wall (see the module docstring).

    Parameters
    ----------
    radius_mm : float
        Wall radius (mm).
    mm_per_px_axial : float
        Axial pixel pitch (mm per column).
    deg_per_px : float
        Circumferential pixel pitch (degrees per row); ``360 / deg_per_px`` must be
        an integer (to 1e-6), so that the rows close up around the pipe.
    z0_mm : float
        Axial position of the centre of column 0 (mm).
    n_cols : int
        Number of columns.

    Raises
    ------
    ValueError
        On a non-positive pitch, radius or column count, or when ``360 / deg_per_px``
        is not an integer.
    """

    radius_mm: float
    mm_per_px_axial: float
    deg_per_px: float
    z0_mm: float
    n_cols: int

    def __post_init__(self) -> None:
        for name in ("radius_mm", "mm_per_px_axial", "deg_per_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"WallGrid.{name}: expected a positive number, got {value!r}")
        if not math.isfinite(self.z0_mm):
            raise ValueError(f"WallGrid.z0_mm: expected a finite number, got {self.z0_mm!r}")
        if int(self.n_cols) != self.n_cols or self.n_cols < 1:
            raise ValueError(f"WallGrid.n_cols: expected a positive integer, got {self.n_cols!r}")
        for name in ("radius_mm", "mm_per_px_axial", "deg_per_px", "z0_mm"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "n_cols", int(self.n_cols))
        self.check_deg_per_px(self.deg_per_px)

    @classmethod
    def check_deg_per_px(cls, deg_per_px: float) -> int:
        """Validate a circumferential pitch and return the row count it implies.

        Parameters
        ----------
        deg_per_px : float
            Degrees per row.

        Returns
        -------
        int
            ``round(360 / deg_per_px)``.

        Raises
        ------
        ValueError
            When ``360 / deg_per_px`` is not within 1e-6 of a positive integer.
        """
        ratio = 360.0 / deg_per_px
        n = round(ratio)
        if n < 1 or abs(ratio - n) > 1e-6:
            raise ValueError(
                f"WallGrid.deg_per_px: 360 / {deg_per_px!r} = {ratio!r} is not an integer; "
                "the rows must close up around the pipe")
        return int(n)

    @property
    def n_rows(self) -> int:
        """Number of rows, ``round(360 / deg_per_px)`` (one full turn)."""
        return round(360.0 / self.deg_per_px)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)``, the shape of an albedo image on this grid."""
        return self.n_rows, int(self.n_cols)

    @property
    def circumference_mm(self) -> float:
        """Wall circumference ``2 pi radius`` (mm)."""
        return 2.0 * math.pi * self.radius_mm

    @property
    def mm_per_px_circ(self) -> float:
        """Arc length of one row step on the wall (mm)."""
        return self.radius_mm * math.radians(self.deg_per_px)

    @property
    def length_mm(self) -> float:
        """Axial extent covered by the columns, ``n_cols * mm_per_px_axial`` (mm)."""
        return self.n_cols * self.mm_per_px_axial

    @classmethod
    def square(cls, radius_mm: float, mm_per_px: float, z0_mm: float,
               z1_mm: float) -> WallGrid:
        """Grid with (nearly) square pixels of ``mm_per_px`` on the wall.

        Parameters
        ----------
        radius_mm : float
            Wall radius (mm).
        mm_per_px : float
            Wanted pixel pitch on the wall, axially and around (mm).
        z0_mm, z1_mm : float
            Axial positions of the first and (about) the last column centre (mm),
            ``z1_mm > z0_mm``.

        Returns
        -------
        WallGrid
            ``mm_per_px_axial = mm_per_px``; ``deg_per_px = 360 / n_rows`` with
            ``n_rows = round(2 pi radius / mm_per_px)``, so the arc pitch is within
            half a row per turn of ``mm_per_px``; ``n_cols = round((z1 - z0) /
            mm_per_px) + 1``.
        """
        if not (radius_mm > 0 and mm_per_px > 0):
            raise ValueError("WallGrid.square: radius_mm and mm_per_px must be positive")
        if not z1_mm > z0_mm:
            raise ValueError(f"WallGrid.square: need z1_mm > z0_mm, got {z0_mm}, {z1_mm}")
        n_rows = max(3, round(2.0 * math.pi * radius_mm / mm_per_px))
        n_cols = round((z1_mm - z0_mm) / mm_per_px) + 1
        return cls(float(radius_mm), float(mm_per_px), 360.0 / n_rows, float(z0_mm), n_cols)

    def theta_z(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre coordinates.

        Returns
        -------
        theta_deg : numpy.ndarray, shape (n_rows,), float64
            Angle of each row (degrees, ``[0, 360)``).
        z_mm : numpy.ndarray, shape (n_cols,), float64
            Axial position of each column (mm).
        """
        theta = np.arange(self.n_rows, dtype=np.float64) * self.deg_per_px
        z = self.z0_mm + np.arange(self.n_cols, dtype=np.float64) * self.mm_per_px_axial
        return theta, z

    def to_json(self) -> dict[str, float]:
        """The SPEC wall-image metadata (``n_cols`` is the image width, not stored).

        Returns
        -------
        dict
            ``{"mm_per_px_axial", "deg_per_px", "z0_mm", "radius_mm"}`` as floats.
        """
        return {"mm_per_px_axial": float(self.mm_per_px_axial),
                "deg_per_px": float(self.deg_per_px),
                "z0_mm": float(self.z0_mm),
                "radius_mm": float(self.radius_mm)}


# --------------------------------------------------------------------------- helpers


def _as_rng(rng: np.random.Generator | int) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, int | np.integer):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng: expected a numpy Generator or an int seed, got {type(rng).__name__}")


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


def _ramp_width(ds: np.ndarray, dz: np.ndarray, dist: np.ndarray, ws: float,
                wz: float) -> np.ndarray:
    """Pixel extent across an edge with normal (ds, dz)/dist, for analytic antialiasing.

    The ramp width whose variance matches that of the pixel footprint projected on
    the normal: ``sqrt((n_s ws)^2 + (n_z wz)^2)``; exactly the pixel pitch for
    square pixels.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.sqrt((ds * ws) ** 2 + (dz * wz) ** 2) / dist
    return np.where(dist > 0, w, math.sqrt(0.5 * (ws * ws + wz * wz)))


def _lattice(grid: WallGrid, cell_s_mm: float, cell_z_mm: float) -> tuple[int, int]:
    """Noise lattice size: spacing ~ the given cells (never much finer than the grid)."""
    cs = max(cell_s_mm, grid.mm_per_px_circ)
    cz = max(cell_z_mm, grid.mm_per_px_axial)
    # FFT-friendly sizes, at most a few % above the grid's own where cs, cz are its pitch.
    n_s = sfft.next_fast_len(max(8, math.ceil(grid.circumference_mm / cs - 1e-6)), real=True)
    n_z = sfft.next_fast_len(max(8, math.ceil(grid.length_mm / cz - 1e-6)), real=True)
    return n_s, n_z


def _filtered_noise(rng: np.random.Generator, shape: tuple[int, int],
                    spacing_mm: tuple[float, float],
                    amplitude: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Periodic Gaussian noise with a given amplitude spectrum, zero mean, unit std.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the white noise.
    shape : (int, int)
        Lattice size (theta, z); the noise is periodic over it in both directions.
    spacing_mm : (float, float)
        Lattice spacing (mm) along theta (arc) and z.
    amplitude : callable
        ``amplitude(f_s, f_z)`` -> filter gain at spatial frequencies in cycles/mm
        (broadcast arrays, float32).
    """
    white = rng.standard_normal(shape, dtype=np.float32)
    spec = sfft.rfft2(white, workers=-1)
    del white
    f_s = sfft.fftfreq(shape[0], d=spacing_mm[0]).astype(np.float32)[:, None]
    f_z = sfft.rfftfreq(shape[1], d=spacing_mm[1]).astype(np.float32)[None, :]
    gain = np.asarray(amplitude(f_s, f_z), dtype=np.float32)
    gain[0, 0] = 0.0
    spec *= gain
    del gain
    out = sfft.irfft2(spec, s=shape, workers=-1).astype(np.float32, copy=False)
    del spec
    std = float(out.std())
    out -= np.float32(out.mean())
    if std > 0:
        out *= np.float32(1.0 / std)
    return out


def _lattice_to_grid(lat: np.ndarray, grid: WallGrid) -> np.ndarray:
    """Resample a periodic lattice covering the whole wall onto the grid (bicubic, wrapped).

    Lattice node (k, l) sits at theta = k * 360 / n_k and z = z0 + l * length / n_l;
    the lattice is periodic in both directions, so the warp wraps (seamless in theta).
    """
    n_rows, n_cols = grid.shape
    if lat.shape == (n_rows, n_cols):
        return np.ascontiguousarray(lat, dtype=np.float32)
    return _scale_wrapped(lat, n_rows, n_cols)


WARP_CHUNK = 8192     # output columns per cv2.warpAffine call (it fails on very wide images)


def _scale_wrapped(src: np.ndarray, n_rows: int, n_cols: int) -> np.ndarray:
    """Bicubic rescale of a periodic image (both axes wrap) to n_rows x n_cols.

    Output node (i, j) samples the source at (i·rows/n_rows, j·cols/n_cols). Done in
    chunks of output columns, each from a wrapped crop of the source with a margin, so
    that OpenCV's remap-based warp never sees a source or output wider than it handles
    (a 20 m wall at full resolution crashed it).
    """
    sy, sx = src.shape[0] / n_rows, src.shape[1] / n_cols
    pad = 4
    rows = np.arange(-pad, src.shape[0] + pad) % src.shape[0]
    chunk = max(1, min(WARP_CHUNK, int(WARP_CHUNK / max(sx, 1.0))))
    out = np.empty((n_rows, n_cols) + src.shape[2:], np.float32)
    for c0 in range(0, n_cols, chunk):
        c1 = min(n_cols, c0 + chunk)
        s0 = int(np.floor(c0 * sx)) - pad
        s1 = int(np.ceil((c1 - 1) * sx)) + pad + 1
        piece = src[rows][:, np.arange(s0, s1) % src.shape[1]]
        m = np.array([[sx, 0.0, c0 * sx - s0], [0.0, sy, float(pad)]])
        out[:, c0:c1] = cv2.warpAffine(piece, m, (c1 - c0, n_rows),
                                       flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                                       borderMode=cv2.BORDER_REPLICATE).reshape(
            (n_rows, c1 - c0) + src.shape[2:])
    return out


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 + 0.5 * np.tanh(0.5 * x)).astype(np.float32, copy=False)


def _multiply_lut(out: np.ndarray, mask: np.ndarray, lut: np.ndarray) -> None:
    """``out *= lut[mask]`` in row chunks (no full-size temporary)."""
    lut = np.ascontiguousarray(lut, dtype=np.float32).reshape(1, 256)
    for r0 in range(0, out.shape[0], _ROW_CHUNK):
        r1 = min(out.shape[0], r0 + _ROW_CHUNK)
        out[r0:r1] *= cv2.LUT(mask[r0:r1], lut)


def _draw_ellipses_wrapped(mask: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                           ax_rows: np.ndarray, ax_cols: np.ndarray, values: np.ndarray,
                           angle_deg: np.ndarray | None = None) -> None:
    """Filled antialiased ellipses on a uint8 image, repeated across the theta wrap.

    Positions and half-axes are in (fractional) pixels; ``values`` 0..255.
    """
    n_rows = mask.shape[0]
    shift = 4
    scale = 1 << shift
    ang = np.zeros(len(rows)) if angle_deg is None else angle_deg
    reach = np.maximum(ax_rows, ax_cols) + 2
    for dy in (0, n_rows, -n_rows):
        sel = slice(None) if dy == 0 else (rows + dy + reach >= 0) & (rows + dy - reach < n_rows)
        if dy != 0 and not np.any(sel):
            continue
        cx = np.rint(cols[sel] * scale).astype(np.int64).tolist()
        cy = np.rint((rows[sel] + dy) * scale).astype(np.int64).tolist()
        ax = np.maximum(1, np.rint(ax_cols[sel] * scale)).astype(np.int64).tolist()
        ay = np.maximum(1, np.rint(ax_rows[sel] * scale)).astype(np.int64).tolist()
        vv = np.asarray(values[sel]).astype(np.int64).tolist()
        aa = np.asarray(ang[sel], dtype=np.float64).tolist()
        for x, y, a, b, v, t in zip(cx, cy, ax, ay, vv, aa, strict=True):
            cv2.ellipse(mask, (x, y), (a, b), t, 0, 360, int(v), -1, cv2.LINE_AA, shift)


# --------------------------------------------------------------------------- chart

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
    w = _ramp_width(du, dv, dist, ws, wz)
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
        w = _ramp_width(du, dv, dist, ws, wz)
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
    rng = _as_rng(rng)
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


# --------------------------------------------------------------------------- corrosion


def corrosion_texture(grid: WallGrid, rng: np.random.Generator | int) -> np.ndarray:
    """Rust / corrosion: fractal noise, stains, bright flakes and pits.

    Built from (all sizes on the wall, mm):

    * fractal (1/f amplitude) noise from ~0.2 mm to ~20 mm, mapped to a lognormal
      albedo (median 0.33, about +-26 %);
    * large stains (1/f^1.5 noise, 2-15 mm blobs) darkening by up to 50 %, and a few
      brighter flakes (bare metal / scale, +0.2) where that field is lowest;
    * pits, ~0.08 per mm^2 and denser in the stains: lognormal diameters
      (median 0.35 mm, 0.08-2 mm), a dark core (x0.28 to x0.5) with a lighter halo.

    The noise is periodic in theta (and along the grid's z extent); pits are drawn
    across the wrap, so the texture is seamless.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source.

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo in [0, 1] (mostly 0.1-0.6).
    """
    rng = _as_rng(rng)
    circ, length = grid.circumference_mm, grid.length_mm
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    # Fine fractal field.
    shape = _lattice(grid, 0.08, 0.08)
    dx = (circ / shape[0], length / shape[1])
    f_hi = 0.35 / max(dx)

    def fractal(fs: np.ndarray, fz: np.ndarray) -> np.ndarray:
        f2 = fs * fs + fz * fz
        gain = np.log(f2 + np.float32(1 / 20.0**2))     # exp/log, not pow: SIMD in numpy
        gain *= np.float32(-0.45)
        f2 *= np.float32(-1.0 / (f_hi * f_hi))
        gain += f2
        return np.exp(gain, out=gain)

    field = _filtered_noise(rng, shape, dx, fractal)
    # Coarse stain field, brought to the fine lattice.
    cshape = (max(8, min(shape[0], math.ceil(circ / 0.5))),
              max(8, min(shape[1], math.ceil(length / 0.5))))
    cdx = (circ / cshape[0], length / cshape[1])

    def blotch(fs: np.ndarray, fz: np.ndarray) -> np.ndarray:
        f2 = fs * fs + fz * fz
        return (f2 + (1 / 15.0) ** 2) ** -0.75 * np.exp(-f2 / 0.5**2)

    stain_c = _filtered_noise(rng, cshape, cdx, blotch)
    # Stains darken (x0.5 at most), flakes brighten (+0.2): computed on the coarse
    # lattice, brought to the fine one as a 2-channel (multiplier, offset) image.
    mult_add = np.dstack([1.0 - 0.5 * _sigmoid((stain_c - 0.4) / 0.3),
                          0.2 * _sigmoid((-stain_c - 1.8) / 0.12)]).astype(np.float32)
    mult_add = _scale_wrapped(mult_add, shape[0], shape[1])
    alb = field                      # lognormal: positive, darker regions compressed
    alb *= np.float32(0.26)
    np.exp(alb, out=alb)
    alb *= np.float32(0.33)
    alb *= mult_add[:, :, 0]
    alb += mult_add[:, :, 1]
    del mult_add
    out = _lattice_to_grid(alb, grid)
    del alb
    # Pits at full resolution.
    n_rows, n_cols = grid.shape
    area = circ * length
    n_cand = int(rng.poisson(0.08 * area / 0.55))
    s_c = rng.uniform(0.0, circ, n_cand)
    z_c = rng.uniform(-0.5 * wz, length - 0.5 * wz, n_cand)
    ks = np.minimum((s_c / cdx[0]).astype(np.int64), cshape[0] - 1)
    kz = np.clip(((z_c + 0.5 * wz) / cdx[1]).astype(np.int64), 0, cshape[1] - 1)
    keep = rng.random(n_cand) < 0.25 + 0.75 * _sigmoid(2.0 * stain_c[ks, kz])
    diam = np.clip(np.exp(rng.normal(math.log(0.35), 0.5, n_cand)), 0.08, 2.0)
    core = rng.uniform(0.5, 1.0, n_cand) * 255.0
    aspect = rng.uniform(0.8, 1.25, n_cand)
    angle = rng.uniform(0.0, 180.0, n_cand)
    s_c, z_c, diam, core, aspect, angle = (x[keep] for x in (s_c, z_c, diam, core, aspect,
                                                             angle))
    rows, cols = s_c / ws, z_c / wz
    r_s = 0.5 * diam * aspect / ws
    r_z = 0.5 * diam / aspect / wz
    mask = np.zeros((n_rows, n_cols), np.uint8)
    _draw_ellipses_wrapped(mask, rows, cols, 1.7 * r_s, 1.7 * r_z, np.full(len(rows), 70.0),
                           angle)
    _draw_ellipses_wrapped(mask, rows, cols, r_s, r_z, core, angle)
    _multiply_lut(out, mask, 1.0 - 0.72 * np.arange(256) / 255.0)
    np.clip(out, 0.0, 1.0, out=out)
    return out


# --------------------------------------------------------------------------- aluminium


def aluminium_texture(grid: WallGrid, rng: np.random.Generator | int) -> np.ndarray:
    """Brushed aluminium: bright, low contrast, fine streaks along the axis.

    Albedo 0.70 with a standard deviation of about 0.018 (2.5 %): fine streaks
    (0.05-1 mm across, ~6 mm correlation length along z), faint isotropic grain
    (>= 0.5 mm), slow mottling (~15 mm) and a few faint near-axial scratches (about
    one per 15 cm^2, 5-40 mm long, +-2 %). Deliberately feature-poor: registration
    has little to lock on to, especially along z.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source.

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo in [0, 1] (essentially 0.63-0.77).
    """
    rng = _as_rng(rng)
    circ, length = grid.circumference_mm, grid.length_mm
    shape = _lattice(grid, 0.04, 0.25)
    dx = (circ / shape[0], length / shape[1])
    fs_hi = 0.35 / dx[0]
    fz_hi = 0.35 / dx[1]
    l_z = 6.0

    def brushed(fs: np.ndarray, fz: np.ndarray) -> np.ndarray:
        cut = np.exp(-(fs / fs_hi) ** 2 - (fz / fz_hi) ** 2)
        streak = (fs * fs + 0.5**2) ** -0.25 * np.exp(-0.5 * (fz * l_z) ** 2)
        f2 = fs * fs + fz * fz
        grain = np.exp(-f2 / 1.0**2)
        mottle = np.exp(-f2 * 15.0**2)
        streak /= math.sqrt(float(np.mean(streak * streak * cut * cut)))
        grain /= math.sqrt(float(np.mean(grain * grain * cut * cut)))
        mottle /= math.sqrt(float(np.mean(mottle * mottle)))
        return (1.0 * streak + 0.35 * grain + 0.6 * mottle) * cut

    alb = _filtered_noise(rng, shape, dx, brushed)
    alb *= np.float32(0.018)
    alb += np.float32(0.70)
    # A few faint scratches, drawn on the lattice (half-widths ~1 lattice node).
    n_scr = int(rng.poisson(circ * length / 1500.0))
    if n_scr:
        s0 = rng.uniform(0.0, circ, n_scr)
        z0 = rng.uniform(0.0, length, n_scr)
        ln = rng.uniform(5.0, 40.0, n_scr)
        tilt = np.deg2rad(rng.normal(0.0, 1.0, n_scr))
        sign = np.where(rng.random(n_scr) < 0.5, -1.0, 1.0)
        strength = rng.uniform(0.008, 0.02, n_scr)
        for polarity in (-1.0, 1.0):
            mask = np.zeros(shape, np.uint8)
            sel = sign == polarity
            for k in np.flatnonzero(sel):
                p0 = (z0[k] / dx[1], s0[k] / dx[0])
                p1 = ((z0[k] + ln[k] * math.cos(tilt[k])) / dx[1],
                      (s0[k] + ln[k] * math.sin(tilt[k])) / dx[0])
                val = round(255 * strength[k] / 0.02)
                for dy in (0.0, shape[0], -shape[0]):
                    cv2.line(mask, (round(p0[0] * 16), round((p0[1] + dy) * 16)),
                             (round(p1[0] * 16), round((p1[1] + dy) * 16)), val, 1,
                             cv2.LINE_AA, 4)
            alb += np.float32(0.02 * polarity / 255.0) * mask
    out = _lattice_to_grid(alb, grid)
    del alb
    np.clip(out, 0.0, 1.0, out=out)
    return out


# --------------------------------------------------------------------------- photo


def _to_unit_grey(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2 or img.shape[0] < 2 or img.shape[1] < 2:
        raise ValueError(f"photo: expected a 2-D grey image of at least 2x2, got {img.shape}")
    if img.dtype == np.uint8:
        out = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        out = img.astype(np.float32) / 65535.0
    elif np.issubdtype(img.dtype, np.floating):
        out = img.astype(np.float32)
        if not np.all(np.isfinite(out)):
            raise ValueError("photo: contains NaN or inf")
    else:
        raise ValueError(f"photo: unsupported dtype {img.dtype}")
    return np.clip(out, 0.0, 1.0)


def photo_texture(grid: WallGrid, image: np.ndarray, tile_mm: float) -> np.ndarray:
    """Tile a grey photo over the wall, mirrored so the tiling has no seams.

    The photo's width spans ``tile_mm`` along z; its height keeps the photo's
    aspect ratio, adjusted (by at most a factor 4/3, usually a few %) so that an
    even number of tiles fits around the circumference: with mirror tiling the
    pattern then closes seamlessly in theta. The photo's rows run around the pipe,
    its columns along z. Resampling: area-averaged with :func:`cv2.resize` to the
    grid's scale, then bicubic with wrap-around (:func:`cv2.warpAffine`) for the
    exact placement. Tile (0, 0) starts at theta = 0 and z = ``grid.z0_mm``.

    Parameters
    ----------
    grid : WallGrid
        Target grid.
    image : numpy.ndarray
        Grey photo, uint8 (0-255), uint16 or float (0-1); BGR(A) is converted to grey.
    tile_mm : float
        Width of one (unmirrored) copy of the photo on the wall, along z (mm).

    Returns
    -------
    numpy.ndarray, shape (n_rows, n_cols), float32
        Albedo in [0, 1].
    """
    if not (math.isfinite(tile_mm) and tile_mm > 0):
        raise ValueError(f"tile_mm: expected a positive number, got {tile_mm!r}")
    img = _to_unit_grey(image)
    h, w = img.shape
    tile_h_mm = tile_mm * h / w
    n_pairs = max(1, round(grid.circumference_mm / (2.0 * tile_h_mm)))
    tile_h_mm = grid.circumference_mm / (2 * n_pairs)
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    # Area prefilter when the photo has more than ~1.5 samples per grid pixel.
    th = min(h, max(2, round(1.5 * tile_h_mm / ws)))
    tw = min(w, max(2, round(1.5 * tile_mm / wz)))
    if (th, tw) != (h, w):
        img = cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA)
    h, w = img.shape
    top = np.concatenate([img, img[:, ::-1]], axis=1)
    period = np.ascontiguousarray(np.concatenate([top, top[::-1]], axis=0))
    # Photo pixel centres at ((k + 0.5) * tile / h) mm: src = pos * h / tile - 0.5.
    mz = wz * w / tile_mm
    ms = ws * h / tile_h_mm
    m = np.array([[mz, 0.0, -0.5], [0.0, ms, -0.5]])
    n_rows, n_cols = grid.shape
    out = cv2.warpAffine(period, m, (n_cols, n_rows), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_WRAP)
    np.clip(out, 0.0, 1.0, out=out)
    return out


# --------------------------------------------------------------------------- defects


@dataclass(frozen=True)
class Defect:
    """A circular defect on the wall.

    Parameters
    ----------
    kind : {"hole", "spot"}
        ``"hole"``: a through hole, drawn almost black (albedo 0.02) with a sharp
        edge; ``"spot"``: a stain that multiplies the albedo by 0.45, with a
        slightly soft edge.
    z_mm : float
        Axial position of the centre (mm).
    theta_deg : float
        Angle of the centre (degrees; any value, taken modulo 360).
    diameter_mm : float
        Diameter on the wall (mm), measured along the surface.
    """

    kind: str
    z_mm: float
    theta_deg: float
    diameter_mm: float

    def __post_init__(self) -> None:
        if self.kind not in DEFECT_KINDS:
            raise ValueError(f"Defect.kind: expected one of {DEFECT_KINDS}, got {self.kind!r}")
        if not (math.isfinite(self.z_mm) and math.isfinite(self.theta_deg)):
            raise ValueError("Defect: z_mm and theta_deg must be finite")
        if not (math.isfinite(self.diameter_mm) and self.diameter_mm > 0):
            raise ValueError(f"Defect.diameter_mm: expected > 0, got {self.diameter_mm!r}")


def _draw_defects_inplace(out: np.ndarray, grid: WallGrid, defects: Iterable[Defect]) -> None:
    n_rows, n_cols = grid.shape
    ws, wz = grid.mm_per_px_circ, grid.mm_per_px_axial
    r_wall = grid.radius_mm
    theta, z = grid.theta_z()
    for d in defects:
        radius = 0.5 * d.diameter_mm
        soft = SPOT_SOFT_FRACTION * d.diameter_mm if d.kind == "spot" else 0.0
        ext = radius + 0.5 * math.hypot(max(ws, wz), soft) + max(ws, wz)
        tc = d.theta_deg % 360.0
        sc = r_wall * math.radians(tc)
        i_lo, i_hi = math.floor((sc - ext) / ws), math.ceil((sc + ext) / ws)
        if i_hi - i_lo + 1 >= n_rows:
            rows = np.arange(n_rows)
        else:
            rows = np.arange(i_lo, i_hi + 1) % n_rows
        j_lo = max(0, math.floor((d.z_mm - ext - grid.z0_mm) / wz))
        j_hi = min(n_cols - 1, math.ceil((d.z_mm + ext - grid.z0_mm) / wz))
        if j_hi < j_lo:
            continue
        dth = (theta[rows] - tc + 180.0) % 360.0 - 180.0
        ds = (r_wall * np.radians(dth))[:, None]
        dz = (z[j_lo:j_hi + 1] - d.z_mm)[None, :]
        dist = np.hypot(ds, dz)
        w = _ramp_width(ds, dz, dist, ws, wz)
        if soft:
            w = np.hypot(w, soft)
        cov = np.clip(0.5 - (dist - radius) / w, 0.0, 1.0).astype(np.float32)
        if rows[0] <= rows[-1] and len(rows) == rows[-1] - rows[0] + 1:
            idx: tuple = (slice(int(rows[0]), int(rows[-1]) + 1), slice(j_lo, j_hi + 1))
        else:
            idx = np.ix_(rows, np.arange(j_lo, j_hi + 1))
        blk = out[idx]
        if d.kind == "hole":
            blk += cov * (np.float32(HOLE_ALBEDO) - blk)
        else:
            blk *= 1.0 - np.float32(1.0 - SPOT_FACTOR) * cov
        out[idx] = blk


def draw_defects(albedo: np.ndarray, grid: WallGrid, defects: Iterable[Defect]) -> np.ndarray:
    """Draw holes and spots, as true circles on the cylinder, onto a copy of ``albedo``.

    The distance from a pixel centre to a defect centre is measured on the wall,
    ``sqrt((radius * dtheta_rad)^2 + dz^2)`` with ``dtheta`` wrapped to
    [-180, 180) degrees, so a defect across theta = 0 is drawn whole. Coverage is
    computed analytically from the signed distance ``d`` to the rim,
    ``clip(0.5 - d / w, 0, 1)`` with ``w`` the pixel's extent across the rim (the
    pixel pitch for square pixels): sub-pixel antialiasing that keeps the area (to
    O(w^2)) and the centre, no blurring. A hole sets the albedo to 0.02
    (``out += cov * (0.02 - out)``); a spot multiplies it by ``1 - 0.55 * cov``
    with its ramp widened to ``hypot(w, 0.12 * diameter)`` (a soft edge still
    centred on the nominal rim). Defects are drawn in order.

    Parameters
    ----------
    albedo : numpy.ndarray, shape grid.shape
        Wall albedo (not modified).
    grid : WallGrid
        Grid of ``albedo``.
    defects : iterable of Defect
        What to draw.

    Returns
    -------
    numpy.ndarray, shape grid.shape, float32
        A new albedo image.
    """
    arr = np.asarray(albedo)
    if arr.shape != grid.shape:
        raise ValueError(f"albedo: shape {arr.shape} does not match the grid {grid.shape}")
    out = np.array(arr, dtype=np.float32, copy=True)
    _draw_defects_inplace(out, grid, defects)
    return out


def reference_test_piece(z_centre_mm: float, theta_centre_deg: float = 90.0,
                         pitch_mm: float = 24.0, diameter_mm: float = 6.0, *,
                         radius_mm: float) -> list[Defect]:
    """The reference test piece: 7 holes in a cross.

    Holes of ``diameter_mm`` at the centre, at +-pitch and +-2 pitch along z, and at
    +-pitch of arc length around the circumference (converted to degrees with
    ``radius_mm``).

    Parameters
    ----------
    z_centre_mm : float
        Axial position of the centre hole (mm).
    theta_centre_deg : float
        Angle of the centre hole (degrees).
    pitch_mm : float
        Hole spacing, axially and as arc length around (mm).
    diameter_mm : float
        Hole diameter (mm).
    radius_mm : float
        Wall radius (mm), keyword-only.

    Returns
    -------
    list of Defect
        In this order: centre; z - 2p, z - p, z + p, z + 2p; arc - p, arc + p
        (angles in [0, 360)).
    """
    if not (radius_mm > 0 and pitch_mm > 0 and diameter_mm > 0):
        raise ValueError("reference_test_piece: radius_mm, pitch_mm and diameter_mm must be > 0")
    dth = math.degrees(pitch_mm / radius_mm)
    t0 = theta_centre_deg % 360.0
    offsets = [(0.0, 0.0), (-2.0, 0.0), (-1.0, 0.0), (1.0, 0.0), (2.0, 0.0),
               (0.0, -1.0), (0.0, 1.0)]
    return [Defect("hole", float(z_centre_mm + kz * pitch_mm), float((t0 + kt * dth) % 360.0),
                   float(diameter_mm)) for kz, kt in offsets]


# --------------------------------------------------------------------------- dispatch


def make_wall(kind: str, grid: WallGrid, *, rng: np.random.Generator | int,
              defects: Iterable[Defect] = (), photo: np.ndarray | None = None,
              photo_tile_mm: float = 30.0) -> np.ndarray:
    """Wall albedo of a given texture, with defects drawn on it.

    Parameters
    ----------
    kind : {"chart", "corrosion", "aluminium", "photo"}
        Texture (see the corresponding ``*_texture`` function).
    grid : WallGrid
        Target grid.
    rng : numpy.random.Generator or int
        Random source (unused for ``"photo"``).
    defects : iterable of Defect
        Drawn after the texture (see :func:`draw_defects`).
    photo : numpy.ndarray, optional
        Grey photo, required for ``kind="photo"``.
    photo_tile_mm : float
        Width of one copy of the photo along z (mm), for ``kind="photo"``.

    Returns
    -------
    numpy.ndarray, shape grid.shape, float32
        Albedo in [0, 1].
    """
    if kind == "chart":
        out = chart_texture(grid, rng)
    elif kind == "corrosion":
        out = corrosion_texture(grid, rng)
    elif kind == "aluminium":
        out = aluminium_texture(grid, rng)
    elif kind == "photo":
        if photo is None:
            raise ValueError('make_wall: kind="photo" needs a photo image')
        out = photo_texture(grid, photo, photo_tile_mm)
    else:
        raise ValueError(f"make_wall: unknown texture {kind!r}; expected one of {TEXTURE_KINDS}")
    _draw_defects_inplace(out, grid, defects)
    return out
