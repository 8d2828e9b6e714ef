"""Compiled inner loops of :mod:`pipestitch.pose.fit` (numba).

Why hand-written: the pose of a frame is a handful of tiny problems (a 6 x 6
conic scatter, a 5-parameter robust least squares, a 2 x 2 closed form) over about
1,400 ring points. No library solves them at this size without a per-call set-up
that dwarfs the arithmetic: ``scipy.optimize.least_squares`` costs ~3 ms per call,
``skimage.measure.ransac`` tens of ms, and the same maths as numpy expressions is
~300 small array calls (~2 ms) per frame. Each kernel here is a plain loop over the
points with arrays in and arrays out; :mod:`pipestitch.pose.fit` holds the logic
around them and the definitions (loss, conic normalisation, closed form) are
documented there.

Conventions: ``pts`` / ``uv`` (N, 2) are in-plane coordinates (mm), a plane point
being d·n + u·e1 + v·e2 in the probe frame (a :class:`Plane`: the fields of
:class:`pipestitch.pose.fit.LaserPlane`); a pose vector is (alpha, beta, dx, dy,
radius); the rotation is R = Rx(alpha)·Ry(beta) (:mod:`pipestitch.geometry.rotations`).
The kernels take their inputs by name: the candidates (:class:`Candidates`), the
camera's compiled unprojection (:class:`pipestitch.camera.base.RayKernel`), the plane
and the fit's settings (:class:`FitSettings`) are named tuples. Nothing here draws
random numbers: RANSAC's samples come from the caller's seeded generator. Every kernel
uses ``error_model="numpy"``: a division by zero gives inf or NaN as the numpy code
did, not an exception (and leaves loops free to vectorise).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)
from pipestitch.camera.base import RayKernel
from pipestitch.camera.kernels import rays_of

EPS = float(np.spacing(1.0))   # skimage's RANSAC clips its trial-count ratio to this
RESELECT_ROUNDS = 4            # re-selections of one candidate per ray
GN_MAX_ITER = 30               # Gauss-Newton iterations at most
STOP_SIGMA = 0.05              # the last Gauss-Newton step: below this many sigmas
JACOBI_SWEEPS = 30             # a bound only: 6 x 6 needs 5 or 6, 2 x 2 one
INVERSE_ITERATIONS = 12        # a bound only: a conic's scatter needs 3 to 6
RMS_POINTS = 128               # px RMS on ~this many ring points: an RMS to ~6 %
MONOMIALS = np.array([[2, 0], [1, 1], [0, 2], [1, 0], [0, 1], [0, 0]])   # x^i y^j of a conic
# Float options of the vectorised loops: reassociation lets LLVM sum in vector lanes.
FAST = {"reassoc", "contract", "nsz", "arcp"}
# A kernel that sets no ``fastmath`` takes its caller's when compiled as its callee, and
# keeps it for every caller after (numba's flags inheritance): so each kernel a FAST one
# calls sets its own, or its code would depend on which caller compiled it first
# (tests/test_kernel_flags.py).
# Numba compiles each kernel into machine code of its own that holds every kernel it
# calls, so a chain of kernels is optimised and compiled again at each level. A kernel
# that only one other calls, as a step of it (the fit's entry levels fit_pixels,
# fit_scaled and fit_frame; refine_both, mirror_of; initial_conic, reselect), is inlined
# into it instead (``inline="always"``: numba's own inlining, the same arithmetic under
# the caller's options): the fit's tree compiles in 24-28 s instead of 42 s (one
# process, its refinement cached). RANSAC's loop (ransac_conic) stays apart: inlined
# into select_ring it slowed every frame's fit.


# --- the kernels' named inputs ----------------------------------------------------------
# Named tuples: numba passes them as structs (free inside compiled code; about a
# microsecond each to type at a call from Python). Their fields' types are part of a
# kernel's signature: scripts/compile_kernels.py lists them.

class Plane(NamedTuple):
    """The laser plane n·p = d as the kernels take it (the fields of
    :class:`pipestitch.pose.fit.LaserPlane`): a plane point (u, v) is
    d·n + u·basis[0] + v·basis[1] in the probe frame."""

    distance_mm: float
    normal: np.ndarray   # (3,) unit normal, float64
    basis: np.ndarray    # (2, 3) in-plane unit vectors, float64


class Candidates(NamedTuple):
    """A frame's ring candidates (the arrays of :class:`pipestitch.pose.ring.RingDetection`)."""

    pixels: np.ndarray    # (N, 2) float64, (col, row)
    azimuth: np.ndarray   # (N,) int64: the ray each lies on
    rank: np.ndarray      # (N,) int64: 0 for its ray's strongest
    n_azimuths: int       # rays searched


class FitSettings(NamedTuple):
    """What a frame's fit is given (:func:`fit_scaled`); lengths on the plane, mm."""

    noise_mm: float        # the point noise: loss scale, gates (NaN: from the frame)
    radius_mm: float       # the radius held when n_free is 4 (NaN when it is fitted)
    n_free: int            # parameters fitted: 4 (radius held) or 5
    min_coverage: float    # below this share of rays with a candidate: NO_RING
    min_hit: int           # fewer rays than this keeping a candidate: LOW_COVERAGE
    max_points: int        # kept ring points returned, subsampled to at most this


# --- the point noise a frame is fitted with (lengths on the laser plane, mm) ------------
# A ring point's noise across the line, per pixel of the line's own sigma (measured on
# the frame: RingDetection.line_sigma_px): a line's centre is found to about a tenth of
# its width on a textured wall. The gates and the robust loss's scale are multiples of
# the point noise, mapped to the plane through the frame's pixel -> plane scale at the
# ring (:func:`ring_scale`), and are widened from the fit's own residuals when the frame
# is noisier (:func:`fit_scaled`). Module constants: numba compiles them in, and a change
# here recompiles the kernels that read them.
NOISE_PER_LINE_SIGMA = 0.12
GATE_SIGMAS = 6.0        # a candidate within this many noise sigmas of the conic is the ring
RESELECT_SIGMAS = 5.0    # ... when the inliers are re-selected, one per ray
RESCALE_RMS = 2.0        # inliers' rms above this many sigmas: the noise was underestimated
RESCALE_ROUNDS = 3
FALLBACK_NOISE_MM = 0.05   # the point noise of a frame whose ring gives no scale


# --- small dense linear algebra (2 x 2 to 6 x 6) ------------------------------------
# Hand-written: through numba, each LAPACK routine costs a few µs a call when warm and
# tens of µs when its code is cold, as it is right after the ring extraction has run;
# a frame needs about twenty of these solves, more than all its arithmetic on points.

@numba.njit(cache=True, error_model="numpy")
def sym_eig(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and unit eigenvectors (columns) of a small symmetric matrix.

    Cyclic Jacobi rotations until the off-diagonal part is at rounding level
    (|off|² <= 1e-30 |diag|², a few sweeps): as accurate as LAPACK's ``syevd``.
    """
    n = a.shape[0]
    if n == 2:
        return _sym_eig2(a[0, 0], a[0, 1], a[1, 1])
    a = a.copy()
    v = np.eye(n)
    for _ in range(JACOBI_SWEEPS):
        off = diag = 0.0
        for p in range(n):
            diag += a[p, p] ** 2
            for q in range(p + 1, n):
                off += a[p, q] ** 2
        if off <= 1e-30 * diag:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                if a[p, q] != 0.0:
                    _rotate(a, v, p, q)
    d = np.diag(a).copy()
    order = argsort_small(d)
    return d[order], v[:, order].copy()


@numba.njit(cache=True, error_model="numpy")
def argsort_small(d: np.ndarray) -> np.ndarray:
    """``np.argsort(d)`` of a few values: numba's argsort sorts up to 15 by insertion,
    as here (same comparison, NaN last, so the same order, ties included); its general
    quicksort is a second of compiling for six numbers."""
    order = np.arange(d.size)
    for i in range(1, d.size):
        k = order[i]
        v = d[k]
        j = i
        while j > 0 and (v < d[order[j - 1]] or (np.isnan(d[order[j - 1]]) and not np.isnan(v))):
            order[j] = order[j - 1]
            j -= 1
        order[j] = k
    return order


@numba.njit(cache=True, error_model="numpy")
def _sym_eig2(a00: float, a01: float, a11: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sym_eig` of [[a00, a01], [a01, a11]]: the one rotation its sweeps make,
    in scalars (the same arithmetic, to the bit). The generic path's array set-up,
    sort and column gather cost ~5 µs here, against ~50 ns of arithmetic, and a frame's
    pose needs three of these (the conic's normalisation and both mirror solutions)."""
    d0, d1, c, s = a00, a11, 1.0, 0.0
    if not a01 * a01 <= 1e-30 * (a00 * a00 + a11 * a11) and a01 != 0.0:
        theta = (a11 - a00) / (2.0 * a01)
        t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
        if theta < 0.0:
            t = -t
        c = 1.0 / np.sqrt(t * t + 1.0)
        s = t * c
        b00, b10 = c * a00 - s * a01, c * a01 - s * a11   # a <- a J (columns) ...
        b01, b11 = s * a00 + c * a01, s * a01 + c * a11
        d0, d1 = c * b00 - s * b10, s * b01 + c * b11     # ... then J^T a (rows)
    vals, vecs = np.empty(2), np.empty((2, 2))
    first = 1 if d1 < d0 else 0                           # ascending, ties in order
    vals[0], vals[1] = (d1, d0) if first else (d0, d1)
    # the columns of v = J: (c, -s) and (s, c)
    vecs[0, 0], vecs[1, 0], vecs[0, 1], vecs[1, 1] = (s, c, c, -s) if first else (c, -s, s, c)
    return vals, vecs


@numba.njit(cache=True, error_model="numpy")
def _rotate(a: np.ndarray, v: np.ndarray, p: int, q: int) -> None:
    """One Jacobi rotation zeroing a[p, q] (a <- J^T a J, v <- v J), in place."""
    theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
    t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
    if theta < 0.0:
        t = -t
    c = 1.0 / np.sqrt(t * t + 1.0)
    s = t * c
    for k in range(a.shape[0]):
        akp, akq = a[k, p], a[k, q]
        a[k, p], a[k, q] = c * akp - s * akq, s * akp + c * akq
    for k in range(a.shape[0]):
        apk, aqk = a[p, k], a[q, k]
        a[p, k], a[q, k] = c * apk - s * aqk, s * apk + c * aqk
        vkp, vkq = v[k, p], v[k, q]
        v[k, p], v[k, q] = c * vkp - s * vkq, s * vkp + c * vkq
    a[p, q] = a[q, p] = 0.0


@numba.njit(cache=True, error_model="numpy")
def lu(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """LU with partial pivoting: (lu, row order, determinant); determinant 0 if singular."""
    n = a.shape[0]
    f = a.copy()
    order = np.arange(n)
    det = 1.0
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(f[i, k]) > abs(f[p, k]):
                p = i
        if f[p, k] == 0.0:
            return f, order, 0.0
        if p != k:
            for j in range(n):
                f[k, j], f[p, j] = f[p, j], f[k, j]
            order[k], order[p] = order[p], order[k]
            det = -det
        det *= f[k, k]
        for i in range(k + 1, n):
            f[i, k] /= f[k, k]
            for j in range(k + 1, n):
                f[i, j] -= f[i, k] * f[k, j]
    return f, order, det


@numba.njit(cache=True, error_model="numpy")
def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b, b (n, m); raises ``numpy.linalg.LinAlgError`` if a is singular."""
    f, order, det = lu(a)
    if det == 0.0:
        raise np.linalg.LinAlgError("Matrix is singular to machine precision.")
    x = np.empty(b.shape)
    for c in range(b.shape[1]):
        col = lu_solve(f, order, np.ascontiguousarray(b[:, c]))
        for r in range(col.size):   # not x[:, c] = col: a slice assignment compiles a
            x[r, c] = col[r]        # shape check with its error message, seconds of code
    return x


@numba.njit(cache=True, error_model="numpy", fastmath=False)
def solve_vector(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b for a vector b (see :func:`solve`)."""
    return solve(a, b.reshape(b.size, 1))[:, 0].copy()


@numba.njit(cache=True, error_model="numpy")
def lu_solve(f: np.ndarray, order: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b for a vector b, from :func:`lu`'s factors of a (non-singular)."""
    n = b.size
    x = np.empty(n)
    for i in range(n):                 # L y = P b
        x[i] = b[order[i]]
        for j in range(i):
            x[i] -= f[i, j] * x[j]
    for i in range(n - 1, -1, -1):     # U x = y
        for j in range(i + 1, n):
            x[i] -= f[i, j] * x[j]
        x[i] /= f[i, i]
    return x


@numba.njit(cache=True, error_model="numpy")
def smallest_eigvec(a: np.ndarray) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of a small positive semi-definite matrix.

    Inverse iteration (a few triangular solves with one LU of ``a``: the smallest
    eigenvalue of a conic's scatter is the fit's residual, far below the next one,
    so each step gains digits by their ratio), checked by its residual
    |a x - (x^T a x) x| against rounding; :func:`sym_eig` when the check fails or
    ``a`` is exactly singular (noise-free points). A tenth of the cost of the Jacobi
    sweeps that diagonalise all of ``a``, for the one vector a conic fit needs.
    """
    n = a.shape[0]
    f, order, det = lu(a)
    norm_a = 0.0
    for i in range(n):
        for j in range(n):
            norm_a = max(norm_a, abs(a[i, j]))
    if det != 0.0:
        x = np.full(n, 1.0 / np.sqrt(n))
        for _ in range(INVERSE_ITERATIONS):
            y = lu_solve(f, order, x)
            y /= np.sqrt(np.sum(y * y))
            if dot(y, x) < 0.0:
                y = -y
            change = np.max(np.abs(y - x))
            x = y
            if change <= 1e-15:
                break
        ax = matvec(a, x)
        lam = dot(ax, x)
        if np.max(np.abs(ax - lam * x)) <= 1e-12 * norm_a:
            return x
    return sym_eig(a)[1][:, 0].copy()


@numba.njit(cache=True, error_model="numpy")
def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a b for small matrices, as loops: numba's ``@`` calls BLAS, whose per-call cost
    (~1 µs) is many times the arithmetic of a 2 x 3 by 3 x 2 product."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            for j in range(b.shape[1]):
                out[i, j] += a[i, k] * b[k, j]
    return out


@numba.njit(cache=True, error_model="numpy")
def matvec(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """a x for a small matrix (see :func:`matmul`)."""
    out = np.zeros(a.shape[0])
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            out[i] += a[i, k] * x[k]
    return out


@numba.njit(cache=True, error_model="numpy")
def dot(a: np.ndarray, b: np.ndarray) -> float:
    """a · b for small vectors (see :func:`matmul`)."""
    total = 0.0
    for i in range(a.size):
        total += a[i] * b[i]
    return total


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def sum_squares(a: np.ndarray) -> float:
    """Σ a² of a long vector (a ring's residuals): reassociated, so LLVM vectorises it
    (:func:`dot`'s plain loop is one chain of dependent additions, ~4x slower here)."""
    total = 0.0
    for i in range(a.size):
        total += a[i] * a[i]
    return total


# --- the conic of the ring in the plane -------------------------------------------

@numba.njit(cache=True, error_model="numpy")
def conic_fit(pts: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """Algebraic conic fit to the masked points (coordinates scaled to unit RMS).

    Returns (coef, scale, ok): a x² + b xy + c y² + d x + e y + f = 0 in coordinates
    divided by ``scale``; ``ok`` is False (coef zero) when it is not an ellipse. The
    conic is the smallest eigenvector of the 6 x 6 scatter of the monomials
    (x², xy, y², x, y, 1), built from the moments sum x^i y^j (i + j <= 4).
    """
    mom = _moments(pts, mask)
    n = mom[0, 0]
    scale = np.sqrt((mom[2, 0] + mom[0, 2]) / n) if n > 0 else 0.0
    if not scale > 0.0:
        scale = 1.0
    scatter = np.empty((6, 6))
    for j in range(6):
        for k in range(6):
            i, m = MONOMIALS[j, 0] + MONOMIALS[k, 0], MONOMIALS[j, 1] + MONOMIALS[k, 1]
            scatter[j, k] = mom[i, m] / scale ** (i + m)
    return _if_ellipse(smallest_eigvec(scatter), scale)


@numba.njit(cache=True, error_model="numpy")
def _if_ellipse(coef: np.ndarray, scale: float) -> tuple[np.ndarray, float, bool]:
    """(coef, scale, True) if the conic is an ellipse (4ac > b²), else zeros and False."""
    if not 4 * coef[0] * coef[2] - coef[1] ** 2 > 0:
        return np.zeros(6), scale, False
    return coef, scale, True


# Vectorised loops (see wall_pass): scalar sums, no zero-division checks, reassociation.
@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _moments(pts: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(5, 5) m with m[i, j] = sum over the masked points of x^i y^j, for i + j <= 4."""
    m00 = m10 = m01 = m20 = m11 = m02 = m30 = m21 = m12 = m03 = 0.0
    m40 = m31 = m22 = m13 = m04 = 0.0
    for k in range(pts.shape[0]):
        # branch-free (a masked-out point adds zeros, even if NaN): the loop vectorises
        on = 1.0 if mask[k] else 0.0
        x = pts[k, 0] if mask[k] else 0.0
        y = pts[k, 1] if mask[k] else 0.0
        xx, xy, yy = x * x, x * y, y * y
        m00 += on
        m10 += x
        m01 += y
        m20 += xx
        m11 += xy
        m02 += yy
        m30 += xx * x
        m21 += xx * y
        m12 += xy * y
        m03 += yy * y
        m40 += xx * xx
        m31 += xx * xy
        m22 += xx * yy
        m13 += xy * yy
        m04 += yy * yy
    return np.array([[m00, m01, m02, m03, m04], [m10, m11, m12, m13, 0.0],
                     [m20, m21, m22, 0.0, 0.0], [m30, m31, 0.0, 0.0, 0.0],
                     [m40, 0.0, 0.0, 0.0, 0.0]])


@numba.njit(cache=True, error_model="numpy")
def conic_through(pts: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """The conic through exactly 5 points, as :func:`conic_fit` returns it.

    The null vector of the 5 x 6 design matrix by Gauss-Jordan elimination with
    complete pivoting: the same conic as the scatter's zero eigenvector, without an
    eigen-solver (RANSAC fits hundreds of these). ``ok`` False when the points do
    not fix one conic (rank < 5) or it is not an ellipse.
    """
    scale = np.sqrt(np.sum(pts**2) / 5)
    if not scale > 0.0:
        return np.zeros(6), 1.0, False
    design = np.empty((5, 6))
    for i in range(5):
        x, y = pts[i, 0] / scale, pts[i, 1] / scale
        design[i, 0], design[i, 1], design[i, 2] = x * x, x * y, y * y
        design[i, 3], design[i, 4], design[i, 5] = x, y, 1.0
    cols = np.arange(6)
    for r in range(5):
        sub = np.abs(design[r:, r:])
        flat = np.argmax(sub)
        i, j = r + flat // (6 - r), r + flat % (6 - r)
        if sub.flat[flat] < 1e-12:
            return np.zeros(6), scale, False
        for c in range(6):   # pivot to (r, r)
            design[r, c], design[i, c] = design[i, c], design[r, c]
        for q in range(5):
            design[q, r], design[q, j] = design[q, j], design[q, r]
        cols[r], cols[j] = cols[j], cols[r]
        for q in range(5):
            if q != r:
                f = design[q, r] / design[r, r]
                for c in range(6):
                    design[q, c] -= f * design[r, c]
    coef = np.empty(6)
    coef[cols[5]] = 1.0
    for r in range(5):
        coef[cols[r]] = -design[r, 5] / design[r, r]
    return _if_ellipse(coef / np.sqrt(np.sum(coef**2)), scale)


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _sampson_at(pts: np.ndarray, i: int, coef: np.ndarray, scale: float) -> float:
    """First-order (Sampson) distance of point i from the conic, data units."""
    x, y = pts[i, 0] / scale, pts[i, 1] / scale
    val = (coef[0] * x * x + coef[1] * x * y + coef[2] * y * y + coef[3] * x + coef[4] * y
           + coef[5])
    gx, gy = 2 * coef[0] * x + coef[1] * y + coef[3], coef[1] * x + 2 * coef[2] * y + coef[4]
    return abs(val) / max(np.sqrt(gx * gx + gy * gy), 1e-12) * scale


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def sampson(pts: np.ndarray, coef: np.ndarray, scale: float) -> np.ndarray:
    """Sampson distance of each point from the conic (:func:`_sampson_at`)."""
    out = np.empty(pts.shape[0])
    for i in range(pts.shape[0]):
        out[i] = _sampson_at(pts, i, coef, scale)
    return out


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _consensus(pts: np.ndarray, coef: np.ndarray, scale: float,
               threshold: float) -> tuple[int, float]:
    """Number of points within ``threshold`` of the conic, and the sum of squared distances."""
    count, total = 0, 0.0
    for i in range(pts.shape[0]):
        dist = _sampson_at(pts, i, coef, scale)
        count += dist < threshold
        total += dist * dist
    return count, total


@numba.njit(cache=True, error_model="numpy")
def conic_normalised(coef: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(Q, lin, c0) in data units, u^T Q u + 2 lin^T u + c0 = 0, max eig(Q) = 1."""
    a, b, c = coef[0], coef[1], coef[2]
    q = np.array([[a, b / 2], [b / 2, c]]) / scale**2
    lam = sym_eig(q)[0]
    norm = lam[1] if lam[0] > 0 else lam[0]   # an ellipse has both eigenvalues of one sign
    lin = np.array([coef[3], coef[4]]) / (2 * scale)
    return q / norm, lin / norm, coef[5] / norm


@numba.njit(cache=True, error_model="numpy", inline="always")
def initial_conic(pts: np.ndarray, rank: np.ndarray, threshold: float) -> tuple[
        np.ndarray, float, np.ndarray, bool, np.ndarray]:
    """Conic of every ray's strongest candidate, and its inliers among all candidates.

    ``ok`` only when >= 12 strongest candidates exist and >= 90 % of them fit;
    the conic is then refitted to all inliers (unless they are all of them: the same
    conic). Otherwise the caller runs RANSAC. The last item is every point's Sampson
    distance from the returned conic when it is at hand (not refitted), else empty.
    """
    strongest = rank == 0
    n_strong = np.count_nonzero(strongest)
    inliers = np.zeros(pts.shape[0], np.bool_)
    none = np.empty(0)
    if n_strong < 12:
        return np.zeros(6), 1.0, inliers, False, none
    coef, scale, ok = conic_fit(pts, strongest)
    if not ok:
        return coef, scale, inliers, False, none
    dist = sampson(pts, coef, scale)
    inliers = strongest & (dist < threshold)
    n_in = np.count_nonzero(inliers)
    if n_in < 0.9 * n_strong:
        return coef, scale, inliers, False, none
    if n_in == n_strong:   # the same points: the same conic
        return coef, scale, inliers, True, dist
    coef2, scale2, ok2 = conic_fit(pts, inliers)
    return coef2, scale2, inliers, ok2, none


@numba.njit(cache=True, error_model="numpy")
def ransac_conic(pts: np.ndarray, uniforms: np.ndarray,
                 threshold: float) -> tuple[np.ndarray, float, np.ndarray, bool]:
    """RANSAC of the conic, as ``skimage.measure.ransac`` (min_samples 5, stop_probability 1).

    Trial k draws 5 distinct points from ``uniforms[k]`` (partial Fisher-Yates), so
    the result is fixed by the caller's seeded generator. The best trial has the
    most inliers (then the smallest sum of squared residuals); the trial count
    shrinks with the best inlier ratio as in skimage. Returns the conic refitted
    to the best inliers.
    """
    n = pts.shape[0]
    inliers = np.zeros(n, np.bool_)
    if n < 5:
        return np.zeros(6), 1.0, inliers, False
    perm = np.arange(n)
    sample = np.empty((5, 2))
    best_num, best_sum = 0, np.inf
    max_trials = uniforms.shape[0]
    k = 0
    while k < max_trials:
        for j in range(5):   # partial Fisher-Yates: 5 distinct points, uniformly
            m = j + int(uniforms[k, j] * (n - j))
            perm[j], perm[m] = perm[m], perm[j]
            sample[j, 0], sample[j, 1] = pts[perm[j], 0], pts[perm[j], 1]
        coef, scale, ok = conic_through(sample)
        k += 1
        if not ok:
            continue
        count, rsum = _consensus(pts, coef, scale, threshold)
        if count > best_num or (count == best_num and rsum < best_sum):
            best_num, best_sum = count, rsum
            inliers = sampson(pts, coef, scale) < threshold
            denom = min(max(1 - (count / n) ** 5, EPS), 1 - EPS)
            max_trials = min(max_trials, int(np.ceil(np.log(EPS) / np.log(denom))))
    if best_num == 0:
        return np.zeros(6), 1.0, inliers, False
    coef, scale, ok = conic_fit(pts, inliers)
    return coef, scale, inliers, ok


@numba.njit(cache=True, error_model="numpy")
def one_per_azimuth(resid: np.ndarray, azimuth: np.ndarray, threshold: float) -> np.ndarray:
    """Mask keeping, per ray, the candidate closest to the model if within threshold.

    Ties go to the first candidate (as a stable sort would).
    """
    best = np.full(azimuth.max() + 1 if azimuth.size else 0, -1)
    for i in range(resid.size):
        a = azimuth[i]
        if best[a] < 0 or resid[i] < resid[best[a]]:
            best[a] = i
    keep = np.zeros(resid.size, np.bool_)
    for i in best:
        if i >= 0 and resid[i] < threshold:
            keep[i] = True
    return keep


@numba.njit(cache=True, error_model="numpy", inline="always")
def reselect(pts: np.ndarray, azimuth: np.ndarray, keep: np.ndarray, coef: np.ndarray,
             scale: float, threshold: float,
             dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Re-select one candidate per ray from the conic and refit, until the set is stable.

    At most ``RESELECT_ROUNDS`` rounds. ``dist``: the points' Sampson distances from
    the given conic if at hand (else empty: computed).
    """
    for k in range(RESELECT_ROUNDS):
        if k > 0 or dist.size != pts.shape[0]:
            dist = sampson(pts, coef, scale)
        new_keep = one_per_azimuth(dist, azimuth, threshold)
        if np.array_equal(new_keep, keep) or np.count_nonzero(new_keep) < 12:
            break
        new_coef, new_scale, ok = conic_fit(pts, new_keep)
        if not ok:
            break
        keep, coef, scale = new_keep, new_coef, new_scale
    return keep, coef, scale


# select_ring's and fit_frame's status
FOUND, NEEDS_SAMPLES, NO_ELLIPSE, NOT_A_SECTION, LOW_COVERAGE, NO_RING = 0, 1, 2, 3, 4, 5
SUMMARY_RMS, SUMMARY_OK, SUMMARY_CORR, SUMMARY_SIGMA = 5, 6, 7, 8   # refine_frame's summary
MIN_CANDIDATES = 12   # fewer ring candidates than this: no ring (status NO_RING)


@numba.njit(cache=True, error_model="numpy")
def select_ring(rays: np.ndarray, candidates: Candidates, plane: Plane, settings: FitSettings,
                uniforms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The ring among the candidates: (uv, kept mask over the N candidates, starts,
    rays hit, status).

    ``rays`` are the unit rays of the N candidates (then of any further pixels:
    ``uv`` holds the plane coordinates of all, :func:`rays_to_plane`).
    :func:`initial_conic` on the candidates that meet the plane (gate
    ``GATE_SIGMAS`` of ``settings.noise_mm``), else :func:`ransac_conic` with
    ``uniforms`` (status NEEDS_SAMPLES when they are empty: call again with them), then
    :func:`reselect` (gate ``RESELECT_SIGMAS`` of it); status NO_ELLIPSE when no conic with >= 12
    inliers exists. ``starts`` are the conic's closed-form poses (:func:`conic_poses`;
    status NOT_A_SECTION when it has none) and ``rays hit`` the number of azimuths
    with a kept candidate.
    """
    azimuth, rank, threshold = candidates.azimuth, candidates.rank, GATE_SIGMAS * settings.noise_mm
    uv, valid = rays_to_plane(rays, plane)
    idx = np.flatnonzero(valid[:azimuth.size])
    # the candidates that meet the plane, gathered in one loop (numba's fancy indexing
    # inlines much generic code, cold right after a ring extraction)
    pts = np.empty((idx.size, 2))
    az, rk = np.empty(idx.size, np.int64), np.empty(idx.size, np.int64)
    for i in range(idx.size):
        j = idx[i]
        pts[i, 0], pts[i, 1], az[i], rk[i] = uv[j, 0], uv[j, 1], azimuth[j], rank[j]
    kept = np.zeros(azimuth.size, np.bool_)
    none = np.empty((0, 5))
    coef, scale, inliers, ok, dist = initial_conic(pts, rk, threshold)
    if not ok:
        if uniforms.shape[0] == 0:
            return uv, kept, none, 0, NEEDS_SAMPLES
        coef, scale, inliers, ok = ransac_conic(pts, uniforms, threshold)
        dist = np.empty(0)   # of another conic
    if not ok or np.count_nonzero(inliers) < 12:
        return uv, kept, none, 0, NO_ELLIPSE
    keep, coef, scale = reselect(pts, az, inliers, coef, scale,
                                 RESELECT_SIGMAS * settings.noise_mm, dist)
    hit = np.zeros(az.max() + 1, np.bool_)
    for i in range(idx.size):
        if keep[i]:
            kept[idx[i]] = hit[az[i]] = True
    starts = conic_poses(*conic_normalised(coef, scale), plane)
    if starts.shape[0] == 0:
        return uv, kept, none, 0, NOT_A_SECTION
    return uv, kept, starts, np.count_nonzero(hit), FOUND


@numba.njit(cache=True, error_model="numpy")
def ring_query(candidates: Candidates) -> tuple[np.ndarray, int, float]:
    """The ring's part of what a fit unprojects (:func:`fit_query`), and the detection's
    coverage, in one call.

    Returns (:func:`step_query` of the pixels at ``stride``, ``stride``, coverage):
    ``stride`` subsamples the rays' strongest candidates to ~128 for the px RMS
    (~6 % on an RMS), coverage is the fraction of the ``n_azimuths`` rays with a
    candidate (:attr:`pipestitch.pose.ring.RingDetection.coverage`).
    """
    pixels, azimuth, rank = candidates.pixels, candidates.azimuth, candidates.rank
    n_azimuths = candidates.n_azimuths
    hit = np.zeros(max(n_azimuths, azimuth.max() + 1 if azimuth.size else 0), np.bool_)
    n_strong = 0
    for i in range(azimuth.size):
        hit[azimuth[i]] = True
        n_strong += rank[i] == 0
    coverage = np.count_nonzero(hit) / n_azimuths if n_azimuths > 0 else 0.0
    stride = max(1, n_strong // RMS_POINTS)
    return step_query(pixels, stride), stride, coverage


@numba.njit(cache=True, error_model="numpy")
def step_query(pixels: np.ndarray, stride: int) -> np.ndarray:
    """(N + 2M, 2): the pixels, then pixels[::stride] moved one column, then one row."""
    n = pixels.shape[0]
    m = (n + stride - 1) // stride
    out = np.empty((n + 2 * m, 2))
    for i in range(n):
        out[i, 0], out[i, 1] = pixels[i, 0], pixels[i, 1]
    for i in range(m):
        out[n + i, 0], out[n + i, 1] = pixels[i * stride, 0] + 1.0, pixels[i * stride, 1]
        out[n + m + i, 0] = pixels[i * stride, 0]
        out[n + m + i, 1] = pixels[i * stride, 1] + 1.0
    return out


# --- the pixel -> plane scale at the ring ------------------------------------------------

RING_SCALE_POINTS = 24   # the scale is the median over this many of the ring's points


@numba.njit(cache=True, error_model="numpy")
def across_query(candidates: Candidates, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the ring's pixel -> plane scale is measured: (2M, 2) pixels and (M,) mask.

    Up to ``n_points`` of the rays' strongest candidates (rank 0, in azimuth order;
    every ``max(1, n // n_points)``-th), then each moved one pixel along the ring's
    normal in the image (the tangent from its neighbouring strongest candidates). The
    mask is False where the tangent has no length (no normal: the step is not taken).
    Empty when fewer than three rays have a strongest candidate.
    """
    rank = candidates.rank
    best = np.flatnonzero(rank == 0)
    n = best.size
    if n < 3:
        return np.empty((0, 2)), np.empty(0, np.bool_)
    pixels = candidates.pixels
    every = max(1, n // n_points)
    m = (n + every - 1) // every
    out = np.empty((2 * m, 2))
    valid = np.empty(m, np.bool_)
    for i in range(m):
        k = i * every
        at, ahead, behind = best[k], best[(k + 1) % n], best[k - 1 if k > 0 else n - 1]
        t_col = pixels[ahead, 0] - pixels[behind, 0]
        t_row = pixels[ahead, 1] - pixels[behind, 1]
        length = np.hypot(t_col, t_row)
        valid[i] = length > 0
        n_col, n_row = (t_row / length, -t_col / length) if valid[i] else (0.0, 0.0)
        out[i, 0], out[i, 1] = pixels[at, 0], pixels[at, 1]
        out[m + i, 0], out[m + i, 1] = pixels[at, 0] + n_col, pixels[at, 1] + n_row
    return out, valid


@numba.njit(cache=True, error_model="numpy")
def median_step(rays: np.ndarray, valid: np.ndarray, plane: Plane) -> float:
    """Median plane distance between the rays of :func:`across_query`'s pixels and of
    their moved copies (mm), over the valid, finite steps; NaN when there is none."""
    m = valid.size
    uv, _ = rays_to_plane(rays, plane)
    steps = np.empty(m)
    count = 0
    for i in range(m):
        step = np.hypot(uv[m + i, 0] - uv[i, 0], uv[m + i, 1] - uv[i, 1])
        if valid[i] and np.isfinite(step):
            steps[count] = step
            count += 1
    if count == 0:
        return np.nan
    steps = np.sort(steps[:count])
    mid = count // 2
    return steps[mid] if count % 2 else 0.5 * (steps[mid - 1] + steps[mid])


@numba.njit(cache=True, error_model="numpy")
def ring_scale(candidates: Candidates, camera: RayKernel, plane: Plane, n_points: int) -> float:
    """:func:`across_query`, the camera's rays and :func:`median_step` in one entry
    (cameras with a compiled unprojection)."""
    query, valid = across_query(candidates, n_points)
    if valid.size == 0:
        return np.nan
    return median_step(rays_of(camera, query), valid, plane)


# --- pose <-> conic -------------------------------------------------------------------

@numba.njit(cache=True, error_model="numpy", fastmath=False)
def rotation_rows(alpha: float, beta: float) -> np.ndarray:
    """(6, 3): rows 0-1 of R = Rx(alpha)·Ry(beta), then of dR/dalpha, then of dR/dbeta."""
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    return np.array([[cb, 0.0, sb], [sa * sb, ca, -sa * cb],
                     [0.0, 0.0, 0.0], [ca * sb, -sa, -ca * cb],
                     [-sb, 0.0, cb], [sa * cb, 0.0, sa * sb]])


@numba.njit(cache=True, error_model="numpy")
def conic_poses(q: np.ndarray, lin: np.ndarray, c0: float, plane: Plane) -> np.ndarray:
    """Closed-form (alpha, beta, dx, dy, radius) of both mirrors; (0, 5) if none.

    See :func:`pipestitch.pose.fit.pose_from_conic` for the derivation.
    """
    distance, normal, basis = plane
    evals, evecs = sym_eig(q)
    w_norm = np.sqrt(max(0.0, 1 - evals[0]))
    r2 = dot(lin, solve_vector(q, lin)) - c0
    if not r2 > 0:
        return np.empty((0, 5))
    minor = evecs[:, 0]
    # the sign numpy's (LAPACK's) eigh gives this vector, so the hypotheses come in
    # the order they always had: first component negative when q01 < 0, else of the
    # sign of q00 - q11 (negative when equal)
    first = -1.0 if q[0, 1] < 0.0 or (q[0, 1] > 0.0 and not q[0, 0] > q[1, 1]) else 1.0
    if q[0, 1] != 0.0 and minor[0] * first < 0.0:
        minor = -minor
    out = np.empty((2, 5))
    for k in range(2):
        w = (1.0 - 2.0 * k) * w_norm * minor
        axis = matvec(np.ascontiguousarray(basis.T), w) + np.sqrt(max(0.0, 1 - dot(w, w))) * normal
        alpha = np.arcsin(min(max(axis[1], -1.0), 1.0))
        beta = np.arcsin(min(max(-axis[0] / np.cos(alpha), -1.0), 1.0))
        rot = rotation_rows(alpha, beta)[:2].copy()
        centre = solve_vector(np.ascontiguousarray(matmul(rot, np.ascontiguousarray(basis.T)).T),
                              lin)
        t = centre - matvec(rot, distance * normal)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = alpha, beta, t[0], t[1]
        out[k, 4] = np.sqrt(r2)
    return out


@numba.njit(cache=True, error_model="numpy")
def plane_to_world(x: np.ndarray, plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """(A, c): plane point u lies at world (x, y) = A u + c for pose vector ``x``."""
    distance, normal, basis = plane
    rot = rotation_rows(x[0], x[1])[:2].copy()
    return matmul(rot, np.ascontiguousarray(basis.T)), matvec(rot, distance * normal) + x[2:4]


@numba.njit(cache=True, error_model="numpy")
def model_conic(x: np.ndarray, plane: Plane) -> tuple[np.ndarray, np.ndarray, float]:
    """The ring conic (q, lin, c0) in plane coordinates of pose vector ``x``."""
    a_mat, c = plane_to_world(x, plane)
    a_t = np.ascontiguousarray(a_mat.T)
    return matmul(a_t, a_mat), matvec(a_t, c), dot(c, c) - x[4] ** 2


@numba.njit(cache=True, error_model="numpy", inline="always")
def mirror_of(x: np.ndarray, plane: Plane) -> np.ndarray:
    """The other pose of x's own conic (farthest in |d alpha| + |d beta|), same radius."""
    sols = conic_poses(*model_conic(x, plane), plane)
    out = x.copy()
    best = -1.0
    for k in range(sols.shape[0]):
        gap = abs(sols[k, 0] - x[0]) + abs(sols[k, 1] - x[1])
        if gap > best:
            best = gap
            for j in range(4):
                out[j] = sols[k, j]
    return out


# --- robust least squares of the radial residuals ---------------------------------------

@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _point_coefficients(x: np.ndarray, plane: Plane) -> np.ndarray:
    """(6, 3) K: row k of :func:`rotation_rows` applied to the plane point of (u, v) is
    K[k, 0] + K[k, 1] u + K[k, 2] v; the offset (dx, dy) is added to rows 0 and 1."""
    distance, normal, basis = plane
    rot = rotation_rows(x[0], x[1])
    out = np.empty((6, 3))
    for k in range(6):
        out[k, 0] = distance * (rot[k, 0] * normal[0] + rot[k, 1] * normal[1]
                                + rot[k, 2] * normal[2])
        for m in range(2):
            out[k, m + 1] = (rot[k, 0] * basis[m, 0] + rot[k, 1] * basis[m, 1]
                             + rot[k, 2] * basis[m, 2])
    out[0, 0] += x[2]
    out[1, 0] += x[3]
    return out


# One pass over the points. The sums are kept in scalars and reassociation lets LLVM
# vectorise the loop and its sums (3x faster than with arrays of sums). Results move
# by float rounding only, and are the same on every call.
@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def wall_pass(x: np.ndarray, u: np.ndarray, v: np.ndarray, plane: Plane,
              f_scale: float) -> tuple[
        np.ndarray, float, float, np.ndarray, np.ndarray, np.ndarray]:
    """Everything one pose vector needs from the plane points (u, v), in one pass.

    The residual of a point p is its radial distance from the wall,
    |R[:2] p + t| - r (mm); its analytic Jacobian row is
    (n·dR_a p, n·dR_b p, n_x, n_y, -1) with n the unit wall normal at the point.
    The soft-L1 loss rho(z) = 2(√(1 + z) − 1) of z = (r/f)² (scipy's definition)
    gives the cost 0.5 f² Σ rho and the IRLS weights w = 1/√(1 + z).

    Returns
    -------
    resid : (N,) residuals; cost : soft-L1 cost; wrr : Σ w r²;
    jtwj, jtwr : weighted normal equations (5 x 5, 5); jtj : unweighted J^T J (5 x 5).
    """
    k = _point_coefficients(x, plane)
    n = u.size
    resid = np.empty(n)
    inv_f = 1.0 / f_scale
    cost = wrr = sw = swr = 0.0
    # weighted sums over the Jacobian entries (a0..a3) = (j0, j1, nx, ny): w a b, w a, w a r
    w00 = w01 = w02 = w03 = w11 = w12 = w13 = w22 = w23 = w33 = 0.0
    wa0 = wa1 = wa2 = wa3 = g0 = g1 = g2 = g3 = 0.0
    plain = PLAIN_ZERO   # unweighted: a b and a (_add_products)
    for i in range(n):
        rho, nx, ny, j0, j1 = _wall_point(k, u[i], v[i])
        r = rho - x[4]
        resid[i] = r
        root = np.sqrt(1.0 + (r * inv_f) * (r * inv_f))
        w = 1.0 / root
        cost += root - 1.0
        wrr += w * r * r
        sw += w
        swr += w * r
        a0, a1, a2, a3 = w * j0, w * j1, w * nx, w * ny
        w00 += a0 * j0
        w01 += a0 * j1
        w02 += a0 * nx
        w03 += a0 * ny
        w11 += a1 * j1
        w12 += a1 * nx
        w13 += a1 * ny
        w22 += a2 * nx
        w23 += a2 * ny
        w33 += a3 * ny
        wa0 += a0
        wa1 += a1
        wa2 += a2
        wa3 += a3
        g0 += a0 * r
        g1 += a1 * r
        g2 += a2 * r
        g3 += a3 * r
        plain = _add_products(plain, j0, j1, nx, ny)
    # the radius column of the Jacobian is -1
    jtwj = _symmetric5((w00, w01, w02, w03, -wa0, w11, w12, w13, -wa1, w22, w23, -wa2, w33,
                        -wa3, sw))
    return (resid, f_scale**2 * cost, wrr, jtwj, np.array([g0, g1, g2, g3, -swr]),
            _plain_jtj(plain, n))


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def plain_pass(x: np.ndarray, u: np.ndarray, v: np.ndarray,
               plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """The residuals and unweighted J^T J of :func:`wall_pass` alone (no loss, no
    weights): what the mirror of an optimum needs (:func:`refine_both`), at about half
    the arithmetic a point."""
    k = _point_coefficients(x, plane)
    n = u.size
    resid = np.empty(n)
    plain = PLAIN_ZERO
    for i in range(n):
        rho, nx, ny, j0, j1 = _wall_point(k, u[i], v[i])
        resid[i] = rho - x[4]
        plain = _add_products(plain, j0, j1, nx, ny)
    return resid, _plain_jtj(plain, n)


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _wall_point(k: np.ndarray, ui: float, vi: float) -> tuple[float, float, float, float,
                                                               float]:
    """The plane point (ui, vi)'s distance rho from the axis, the unit wall normal
    (nx, ny) there and the tilt columns (j0, j1) of its Jacobian row
    (:func:`wall_pass`; ``k`` from :func:`_point_coefficients`)."""
    qx = k[0, 0] + k[0, 1] * ui + k[0, 2] * vi
    qy = k[1, 0] + k[1, 1] * ui + k[1, 2] * vi
    rho = np.sqrt(qx * qx + qy * qy)
    nx, ny = qx / rho, qy / rho
    j0 = (nx * (k[2, 0] + k[2, 1] * ui + k[2, 2] * vi)
          + ny * (k[3, 0] + k[3, 1] * ui + k[3, 2] * vi))
    j1 = (nx * (k[4, 0] + k[4, 1] * ui + k[4, 2] * vi)
          + ny * (k[5, 0] + k[5, 1] * ui + k[5, 2] * vi))
    return rho, nx, ny, j0, j1


# The unweighted sums of a pass: the ten products of (j0, j1, nx, ny) (upper triangle,
# row by row), then the four themselves. A tuple of scalars, which LLVM keeps in
# registers and vectorises as separate sums.
PLAIN_ZERO = (0.0,) * 14


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _add_products(sums: tuple, j0: float, j1: float, nx: float, ny: float) -> tuple:
    """``sums`` (:data:`PLAIN_ZERO`'s order) with one point's products added."""
    h00, h01, h02, h03, h11, h12, h13, h22, h23, h33, s0, s1, s2, s3 = sums
    return (h00 + j0 * j0, h01 + j0 * j1, h02 + j0 * nx, h03 + j0 * ny, h11 + j1 * j1,
            h12 + j1 * nx, h13 + j1 * ny, h22 + nx * nx, h23 + nx * ny, h33 + ny * ny,
            s0 + j0, s1 + j1, s2 + nx, s3 + ny)


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _plain_jtj(sums: tuple, n: int) -> np.ndarray:
    """The unweighted J^T J (5 x 5) of ``n`` points' :func:`_add_products` sums (the
    radius column of the Jacobian is -1)."""
    h00, h01, h02, h03, h11, h12, h13, h22, h23, h33, s0, s1, s2, s3 = sums
    return _symmetric5((h00, h01, h02, h03, -s0, h11, h12, h13, -s1, h22, h23, -s2, h33, -s3,
                        float(n)))


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def _symmetric5(upper: tuple[float, ...]) -> np.ndarray:
    """The symmetric 5 x 5 matrix with the upper triangle ``upper`` (15 values, row by row)."""
    m00, m01, m02, m03, m04, m11, m12, m13, m14, m22, m23, m24, m33, m34, m44 = upper
    return np.array([[m00, m01, m02, m03, m04], [m01, m11, m12, m13, m14],
                     [m02, m12, m22, m23, m24], [m03, m13, m23, m33, m34],
                     [m04, m14, m24, m34, m44]])


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def residual_pass(x: np.ndarray, u: np.ndarray, v: np.ndarray, plane: Plane,
                  f_scale: float) -> tuple[np.ndarray, float]:
    """The residuals and soft-L1 cost of :func:`wall_pass` alone (no Jacobian)."""
    k = _point_coefficients(x, plane)
    resid = np.empty(u.size)
    inv_f = 1.0 / f_scale
    cost = 0.0
    for i in range(u.size):
        qx = k[0, 0] + k[0, 1] * u[i] + k[0, 2] * v[i]
        qy = k[1, 0] + k[1, 1] * u[i] + k[1, 2] * v[i]
        r = np.sqrt(qx * qx + qy * qy) - x[4]
        resid[i] = r
        cost += np.sqrt(1.0 + (r * inv_f) * (r * inv_f)) - 1.0
    return resid, f_scale**2 * cost


@numba.njit(cache=True, error_model="numpy")
def gauss_newton(x: np.ndarray, u: np.ndarray, v: np.ndarray, plane: Plane, n_free: int,
                 f_scale: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Damped IRLS Gauss-Newton; ends with a step below ``STOP_SIGMA`` of every
    parameter's sigma, taken with the residuals alone (:func:`residual_pass`).

    Each iteration shrinks the step ~5x from the closed-form start, so the last step
    leaves x within ~1 % of a sigma of the optimum; J^T J is kept from the point it
    was taken at, a twentieth of a sigma away (the same to ~1e-6 relative). This
    saves one full pass on most frames, where stopping before a step of 2 % took one
    more. Only the first ``n_free`` parameters move (4: the radius is held). Returns
    (x, cost, residuals at x, unweighted J^T J). Raises
    ``numpy.linalg.LinAlgError`` when the normal equations are singular.
    """
    x = x.copy()
    resid, cost, wrr, hess, grad, jtj = wall_pass(x, u, v, plane, f_scale)
    damping = 1e-9
    dof = max(1, u.size - n_free)
    for _ in range(GN_MAX_ITER):
        a = hess[:n_free, :n_free].copy()
        damped = a.copy()
        for j in range(n_free):
            damped[j, j] += damping * a[j, j]
        step = solve_vector(damped, -grad[:n_free])
        trial = x.copy()
        for j in range(n_free):
            trial[j] += step[j]
        # sigma of each parameter (weighted normal equations, residual variance)
        sigma2 = np.diag(solve(a, np.eye(n_free))) * max(wrr / dof, 1e-12)
        if np.all(step**2 <= STOP_SIGMA**2 * sigma2):
            last = residual_pass(trial, u, v, plane, f_scale)
            if last[1] <= cost:
                x, (resid, cost) = trial, last
            break
        out = wall_pass(trial, u, v, plane, f_scale)
        if out[1] <= cost:
            x, (resid, cost, wrr, hess, grad, jtj) = trial, out
            damping /= 10
        else:
            damping = max(damping * 10, 1e-6)
            if damping > 1e6:
                break
    return x, cost, resid, jtj


@numba.njit(cache=True, error_model="numpy", inline="always")
def refine_both(start: np.ndarray, u: np.ndarray, v: np.ndarray, plane: Plane, n_free: int,
                f_scale: float) -> tuple[
        np.ndarray, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`gauss_newton` from ``start``, then the mirror of the optimum.

    Returns (x, cost, resid, jtj) of the optimum and (mirror, resid, jtj) of its
    mirror (:func:`mirror_of`), residuals and unweighted J^T J at each.
    """
    x, cost, resid, jtj = gauss_newton(start, u, v, plane, n_free, f_scale)
    mirror = mirror_of(x, plane)
    m_resid, m_jtj = plain_pass(mirror, u, v, plane)
    return x, cost, resid, jtj, mirror, m_resid, m_jtj


@numba.njit(cache=True, error_model="numpy")
def refine_frame(start: np.ndarray, uv: np.ndarray, kept: np.ndarray, stride: int,
                 plane: Plane, settings: FitSettings) -> tuple[
        np.ndarray, float, float, np.ndarray]:
    """Both hypotheses of a frame from the kept candidates, with their statistics.

    ``uv`` are the plane coordinates of the N candidates (``kept`` marks the ring's),
    then of candidates[::stride] moved one column, then one row (:func:`step_query`,
    for :func:`px_rms`). The least squares (:func:`refine_both`) fits the first
    ``settings.n_free`` parameters of ``start`` with the loss scale
    ``settings.noise_mm``. Returns (summary, cost, rms_px, information
    (2, 4, 4)); row 0 of the summary is the optimum, row 1 its mirror, each the pose
    vector (5), then at SUMMARY_RMS its rms_mm, at SUMMARY_OK 1.0 where its sigma is
    valid, at SUMMARY_CORR its residuals' :func:`correlation_factor`, and from
    SUMMARY_SIGMA the sigma of the n_free parameters.
    """
    n_free = settings.n_free
    n = kept.size
    m = (n + stride - 1) // stride
    idx = np.flatnonzero(kept)
    u, v = np.empty(idx.size), np.empty(idx.size)
    for i in range(idx.size):
        u[i], v[i] = uv[idx[i], 0], uv[idx[i], 1]
    x, cost, resid, jtj, mirror, m_resid, m_jtj = refine_both(start, u, v, plane, n_free,
                                                              settings.noise_mm)
    # px RMS on the kept points of the subsample the steps were taken at: candidate
    # k * stride, its residual (the kept points' running count) and its two steps
    pts, res = np.empty((m, 2)), np.empty(m)
    col, row = np.empty((m, 2)), np.empty((m, 2))
    count = position = 0
    for i in range(n):
        if kept[i] and i % stride == 0:
            k = i // stride
            res[count] = resid[position]
            for j in range(2):   # element by element (see the summary below)
                pts[count, j], col[count, j] = uv[i, j], uv[n + k, j]
                row[count, j] = uv[n + m + k, j]
            count += 1
        position += kept[i]
    a_mat, c = plane_to_world(x, plane)
    rms_px = px_rms(pts[:count], res[:count], col[:count], row[:count], a_mat, c)
    # one row per hypothesis, so Python converts one array (each conversion has a cost)
    summary, info = np.empty((2, SUMMARY_SIGMA + n_free)), np.empty((2, 4, 4))
    for j in range(5):   # element by element: slice assignments compile a shape check
        summary[0, j], summary[1, j] = x[j], mirror[j]
    # the mirror's residuals are the optimum's (the same conic: equal to ~1e-14 mm), so
    # their correlation along the ring is one figure for both
    corr = correlation_factor(resid, u, v)
    for h, (r, h_jtj) in enumerate(((resid, jtj), (m_resid, m_jtj))):
        squares = sum_squares(r)
        summary[h, SUMMARY_RMS] = np.sqrt(squares / r.size)
        sigma, pose_info, ok = uncertainty(squares, r.size, h_jtj, n_free)
        for i in range(4):
            for j in range(4):
                info[h, i, j] = pose_info[i, j]
        summary[h, SUMMARY_OK] = 1.0 if ok else 0.0
        summary[h, SUMMARY_CORR] = corr
        for j in range(n_free):
            summary[h, SUMMARY_SIGMA + j] = sigma[j]
    return summary, cost, rms_px, info


@numba.njit(cache=True, error_model="numpy", inline="always")
def fit_frame(rays: np.ndarray, stride: int, candidates: Candidates, plane: Plane,
              settings: FitSettings, uniforms: np.ndarray) -> tuple:
    """A frame's whole fit in one call: :func:`select_ring`, then :func:`refine_frame`
    from the first closed-form start, then :func:`ring_subsample` of the kept points,
    with the point noise ``settings.noise_mm``.

    One entry from Python instead of three: right after a ring extraction every entry's
    argument handling and code are cold, and cost more than the arithmetic. ``rays``
    and ``stride`` are the unit rays of :func:`ring_query`'s pixels (rows after them
    are not read) and its stride;
    ``settings.radius_mm`` replaces the start's radius when ``settings.n_free`` is 4
    (held); ``settings.min_hit`` rays must keep a candidate (else status LOW_COVERAGE);
    ``uniforms`` are RANSAC's samples (:func:`select_ring`).

    Returns
    -------
    (status, rays hit, points kept, summary, cost, rms_px, information, ring uv, ring
    pixels): the last six as :func:`refine_frame` and :func:`ring_subsample` give them,
    empty unless status is FOUND.
    """
    uv, kept, starts, hit, status = select_ring(rays, candidates, plane, settings, uniforms)
    if status == FOUND and hit < settings.min_hit:
        status = LOW_COVERAGE
    if status != FOUND:
        return no_fit(status, hit, settings.n_free)
    start = starts[0].copy()
    if settings.n_free == 4:
        start[4] = settings.radius_mm
    summary, cost, rms_px, info = refine_frame(start, uv, kept, stride, plane, settings)
    ring_uv, ring_px = ring_subsample(uv[:kept.size], candidates.pixels, kept,
                                      settings.max_points)
    return (status, hit, np.count_nonzero(kept), summary, cost, rms_px, info, ring_uv, ring_px)


@numba.njit(cache=True, error_model="numpy")
def no_fit(status: int, hit: int, n_free: int) -> tuple:
    """:func:`fit_frame`'s result without a fit: the status and empty arrays."""
    ring = np.empty((0, 2), np.float32)
    return (status, hit, 0, np.empty((0, SUMMARY_SIGMA + n_free)), 0.0, 0.0,
            np.empty((0, 4, 4)), ring, ring)


@numba.njit(cache=True, error_model="numpy")
def fit_query(candidates: Candidates) -> tuple[np.ndarray, int, float, np.ndarray]:
    """Every pixel a frame's fit unprojects, and the detection's coverage, in one call.

    Returns (pixels, stride, coverage, mask): :func:`ring_query`'s pixels, then
    :func:`across_query`'s (where the frame's pixel -> plane scale is measured: the
    last 2M rows, M the mask's length), the stride and coverage of
    :func:`ring_query`, and the mask of :func:`across_query`.
    """
    query, stride, found = ring_query(candidates)
    across, valid = across_query(candidates, RING_SCALE_POINTS)
    n = query.shape[0]
    out = np.empty((n + across.shape[0], 2))
    for i in range(n):
        out[i, 0], out[i, 1] = query[i, 0], query[i, 1]
    for i in range(across.shape[0]):
        out[n + i, 0], out[n + i, 1] = across[i, 0], across[i, 1]
    return out, stride, found, valid


@numba.njit(cache=True, error_model="numpy")
def has_ring(candidates: Candidates, coverage: float, settings: FitSettings) -> bool:
    """Whether a frame has enough candidates to fit (else status NO_RING): at least
    ``MIN_CANDIDATES``, on at least ``settings.min_coverage`` of the rays."""
    return (candidates.pixels.shape[0] >= MIN_CANDIDATES
            and coverage >= settings.min_coverage)


@numba.njit(cache=True, error_model="numpy")
def _with_noise(settings: FitSettings, noise_mm: float) -> FitSettings:
    """``settings`` with the point noise ``noise_mm``."""
    return FitSettings(noise_mm, settings.radius_mm, settings.n_free, settings.min_coverage,
                       settings.min_hit, settings.max_points)


@numba.njit(cache=True, error_model="numpy", inline="always")
def fit_scaled(rays: np.ndarray, stride: int, valid: np.ndarray, candidates: Candidates,
               plane: Plane, settings: FitSettings, line_sigma_px: float,
               uniforms: np.ndarray) -> tuple:
    """A frame's fit with its point noise: (noise, :func:`fit_frame`'s tuple).

    ``rays`` are the unit rays of :func:`fit_query`'s pixels (``stride`` and the mask
    ``valid`` are its). With ``settings.noise_mm`` finite the frame is fitted with that
    noise. With NaN the noise is the frame's own: ``NOISE_PER_LINE_SIGMA`` of the
    line's measured sigma (``line_sigma_px``) times the ring's pixel -> plane scale
    (:func:`median_step` of the last rays; ``FALLBACK_NOISE_MM`` when there is none).
    A fit with too few inliers (LOW_COVERAGE, NO_ELLIPSE) is then tried once more with
    a three times wider noise, and while the inliers' rms exceeds ``RESCALE_RMS``
    noise sigmas (their scatter fills the gate: the frame is noisier than its line
    width says) the fit is repeated, at most ``RESCALE_ROUNDS`` times, with the noise
    set from that rms (1.3 x: the gate truncates the scatter). A fit that returns
    NEEDS_SAMPLES is returned at once: the caller calls again with RANSAC's samples.

    One compiled entry for all of it: right after a ring extraction every entry from
    Python is cold, and the frame's scale and the rescaling rounds reuse the rays.
    """
    noise = settings.noise_mm
    if np.isfinite(noise):
        return noise, fit_frame(rays, stride, candidates, plane, settings, uniforms)
    scale = np.nan
    if valid.size > 0:
        scale = median_step(rays[rays.shape[0] - 2 * valid.size:], valid, plane)
    noise = NOISE_PER_LINE_SIGMA * line_sigma_px * scale
    if not np.isfinite(noise):   # no candidate meets the plane: nothing to scale by
        noise = FALLBACK_NOISE_MM
        return noise, fit_frame(rays, stride, candidates, plane, _with_noise(settings, noise),
                                uniforms)
    out = fit_frame(rays, stride, candidates, plane, _with_noise(settings, noise), uniforms)
    if out[0] == LOW_COVERAGE or out[0] == NO_ELLIPSE:
        wider = fit_frame(rays, stride, candidates, plane,
                          _with_noise(settings, 3.0 * noise), uniforms)
        if wider[0] == FOUND or wider[0] == NEEDS_SAMPLES:
            noise, out = 3.0 * noise, wider
    for _ in range(RESCALE_ROUNDS):
        if out[0] != FOUND or out[3][0, SUMMARY_RMS] <= RESCALE_RMS * noise:
            break
        wider_noise = 1.3 * out[3][0, SUMMARY_RMS]
        wider = fit_frame(rays, stride, candidates, plane, _with_noise(settings, wider_noise),
                          uniforms)
        if wider[0] == NEEDS_SAMPLES:
            return wider_noise, wider
        if wider[0] != FOUND:
            break
        noise, out = wider_noise, wider
    return noise, out


@numba.njit(cache=True, error_model="numpy", inline="always")
def fit_pixels(candidates: Candidates, camera: RayKernel, plane: Plane, settings: FitSettings,
               line_sigma_px: float, uniforms: np.ndarray) -> tuple:
    """:func:`fit_query`, the camera's rays of it and :func:`fit_scaled`: one entry.

    For cameras with a compiled unprojection (``camera``: its ``ray_kernel``), so that
    a frame enters compiled code once. Returns (detection coverage, noise,
    :func:`fit_frame`'s tuple); status NO_RING (noise NaN) without unprojecting when
    :func:`has_ring` says so.
    """
    query, stride, found, valid = fit_query(candidates)
    if not has_ring(candidates, found, settings):
        # values, not constants: numba compiles a kernel once for each constant argument
        return found, np.nan, no_fit(np.int64(NO_RING), np.int64(0), settings.n_free)
    noise, out = fit_scaled(rays_of(camera, query), stride, valid, candidates, plane, settings,
                            line_sigma_px, uniforms)
    return found, noise, out


@numba.njit(cache=True, error_model="numpy")
def fit_fields(pixels: np.ndarray, azimuth: np.ndarray, rank: np.ndarray, n_azimuths: int,
               kind: int, a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
               index: np.ndarray, distance_mm: float, normal: np.ndarray, basis: np.ndarray,
               noise_mm: float, radius_mm: float, n_free: int, min_coverage: float,
               min_hit: int, max_points: int, line_sigma_px: float,
               uniforms: np.ndarray) -> tuple:
    """:func:`fit_pixels` with its named tuples passed field by field, in their order
    (:class:`Candidates`, :class:`pipestitch.camera.base.RayKernel`, :class:`Plane`,
    :class:`FitSettings`): the entry from Python. Numba's dispatcher types a named
    tuple in Python code, ~25 µs a call for these four right after a ring extraction
    (their code cold), arrays and numbers in compiled code (measured: ~5 µs)."""
    return fit_pixels(Candidates(pixels, azimuth, rank, n_azimuths),
                      RayKernel(kind, a, b, c, d, index), Plane(distance_mm, normal, basis),
                      FitSettings(noise_mm, radius_mm, n_free, min_coverage, min_hit,
                                  max_points), line_sigma_px, uniforms)


@numba.njit(cache=True, error_model="numpy")
def ring_subsample(uv: np.ndarray, pixels: np.ndarray, kept: np.ndarray,
                   max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th kept point (k the smallest giving <= max_points): uv and pixels, float32."""
    idx = np.flatnonzero(kept)
    idx = idx[::max(1, -(-idx.size // max_points))]
    return take_rows(uv, idx).astype(np.float32), take_rows(pixels, idx).astype(np.float32)


@numba.njit(cache=True, error_model="numpy")
def take_rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` for an (N, 2) array, element by element: copying row views in a loop
    (``out[i] = a[idx[i]]``) costs ~20 ns a row in numba, ten times this."""
    out = np.empty((idx.size, 2))
    for i in range(idx.size):
        out[i, 0], out[i, 1] = a[idx[i], 0], a[idx[i], 1]
    return out


@numba.njit(cache=True, error_model="numpy", fastmath=FAST)
def correlation_factor(resid: np.ndarray, u: np.ndarray, v: np.ndarray) -> float:
    """How many times fewer independent residuals a ring holds than points, from their
    autocorrelation along the ring: 1 + 2 (rho_1 + rho_2 + ...), summed while it is
    significant (above 2 / sqrt(n); at most a quarter of the points' lags).

    The points (plane coordinates ``u``, ``v``) are in ray order. Neighbouring rays read
    overlapping pixels of the line, and speckle, a smudge on the lens or an arc of faint
    line move whole stretches of the ring together; the variance of a fit to n such
    residuals is about this many times that of n independent ones (the effective sample
    size of a correlated series). The residuals' harmonics 0-2 around the ring are
    removed first: a section the model does not hold (an oval fitted as a circle) leaves
    a cos 2 theta pattern that the pose's parameters are orthogonal to. The harmonics
    come from u / r and v / r (no trigonometric call), their normal matrix has a ridge
    of 1e-9 n.

    Every sum over the points is a scalar in a reassociated loop, which LLVM vectorises:
    a plain sum is one chain of dependent additions, several times slower on a ring's
    ~1,400 points; results move by float rounding only, the same on every call.
    """
    n = resid.size
    if n < 8:
        return 1.0
    cos, sin = np.empty(n), np.empty(n)
    # sums over the points: x_ of x, x_y of x times y; e_x of the residual times x
    c_ = s_ = c2_ = s2_ = c_c = c_s = c_c2 = c_s2 = s_s = s_c2 = s_s2 = c2_c2 = c2_s2 = 0.0
    s2_s2 = e_ = e_c = e_s = e_c2 = e_s2 = 0.0
    for i in range(n):
        r = np.sqrt(u[i] * u[i] + v[i] * v[i])
        c, s = (u[i] / r, v[i] / r) if r > 0.0 else (1.0, 0.0)
        cos[i], sin[i] = c, s
        c2, s2, e = c * c - s * s, 2.0 * s * c, resid[i]
        c_ += c
        s_ += s
        c2_ += c2
        s2_ += s2
        c_c += c * c
        c_s += c * s
        c_c2 += c * c2
        c_s2 += c * s2
        s_s += s * s
        s_c2 += s * c2
        s_s2 += s * s2
        c2_c2 += c2 * c2
        c2_s2 += c2 * s2
        s2_s2 += s2 * s2
        e_ += e
        e_c += e * c
        e_s += e * s
        e_c2 += e * c2
        e_s2 += e * s2
    ridge = 1e-9 * n
    normal = np.array([[n + ridge, c_, s_, c2_, s2_], [c_, c_c + ridge, c_s, c_c2, c_s2],
                       [s_, c_s, s_s + ridge, s_c2, s_s2], [c2_, c_c2, s_c2, c2_c2 + ridge, c2_s2],
                       [s2_, c_s2, s_s2, c2_s2, s2_s2 + ridge]])
    k0, k1, k2, k3, k4 = solve_vector(normal, np.array([e_, e_c, e_s, e_c2, e_s2]))
    rest = np.empty(n)
    var = 0.0
    for i in range(n):
        c, s = cos[i], sin[i]
        rest[i] = resid[i] - (k0 + k1 * c + k2 * s + k3 * (c * c - s * s) + k4 * (2.0 * s * c))
        var += rest[i] * rest[i]
    if var <= 0.0:
        return 1.0
    floor = 2.0 / np.sqrt(n)
    factor = 1.0
    for k in range(1, n // 4):
        lagged = 0.0
        for i in range(n - k):
            lagged += rest[i] * rest[i + k]
        rho = lagged / var
        if rho <= floor:
            break
        factor += 2.0 * rho
    return factor


@numba.njit(cache=True, error_model="numpy")
def uncertainty(squares: float, n: int, jtj: np.ndarray,
                n_free: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """1-sigma of the free parameters and the pose's 4 x 4 information matrix.

    From the plain (unweighted) J^T J and the sum of the ``n`` residuals' squares
    (:func:`sum_squares`), as if the residuals were
    independent (:func:`correlation_factor` says by how much they are not); with the
    radius free (n_free 5) it is marginalised out of the information (Schur
    complement). ``ok`` False (sigma NaN) when the information is singular.
    """
    dof = max(1, n - n_free)
    info = jtj[:n_free, :n_free] / max(squares / dof, 1e-12)
    pose_info = info[:4, :4].copy()
    if n_free == 5:   # loops, not np.outer and an array expression: less code to compile
        scale = max(info[4, 4], 1e-300)
        for i in range(4):
            for j in range(4):
                pose_info[i, j] -= info[i, 4] * info[4, j] / scale
    sigma = np.full(n_free, np.nan)
    if lu(info)[2] == 0.0:
        return sigma, pose_info, False
    cov = solve(info, np.eye(n_free))
    for j in range(n_free):
        sigma[j] = np.sqrt(max(cov[j, j], 0.0))
    return sigma, pose_info, True


# --- plane points and the image-side residual -------------------------------------------

@numba.njit(cache=True, error_model="numpy")
def rays_to_plane(rays: np.ndarray, plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """In-plane coordinates (N, 2) where each ray meets the plane n·p = d, and the mask.

    Rows of rays that miss the plane (behind it, grazing, NaN) are NaN.
    """
    distance, normal, basis = plane
    n = rays.shape[0]
    valid = np.empty(n, np.bool_)
    uv = np.empty((n, 2))
    for i in range(n):
        along = rays[i, 0] * normal[0] + rays[i, 1] * normal[1] + rays[i, 2] * normal[2]
        valid[i] = along > 1e-6    # False for NaN: then the plane point is NaN too
        scale = distance / along if valid[i] else np.nan
        for k in range(2):
            uv[i, k] = scale * (rays[i, 0] * basis[k, 0] + rays[i, 1] * basis[k, 1]
                                + rays[i, 2] * basis[k, 2])
    return uv, valid


@numba.njit(cache=True, error_model="numpy")
def px_rms(uv: np.ndarray, resid: np.ndarray, uv_col: np.ndarray, uv_row: np.ndarray,
           a_mat: np.ndarray, c: np.ndarray) -> float:
    """RMS pixel offset of radial wall residuals moved along their rays in the plane.

    ``uv_col``, ``uv_row``: plane coordinates of each pixel moved by one column, one
    row (NaN where it misses the plane) — the local pixel -> plane Jacobian.
    """
    total, count = 0.0, 0
    for i in range(uv.shape[0]):
        u0, u1 = uv[i, 0], uv[i, 1]
        qx = a_mat[0, 0] * u0 + a_mat[0, 1] * u1 + c[0]
        qy = a_mat[1, 0] * u0 + a_mat[1, 1] * u1 + c[1]
        qn = np.sqrt(qx * qx + qy * qy)
        un = np.sqrt(u0 * u0 + u1 * u1)
        h0, h1 = u0 / un, u1 / un
        along = (qx * (a_mat[0, 0] * h0 + a_mat[0, 1] * h1)
                 + qy * (a_mat[1, 0] * h0 + a_mat[1, 1] * h1)) / qn
        du0, du1 = h0 * resid[i] / along, h1 * resid[i] / along
        j00, j10 = uv_col[i, 0] - u0, uv_col[i, 1] - u1   # d(uv)/d(col)
        j01, j11 = uv_row[i, 0] - u0, uv_row[i, 1] - u1   # d(uv)/d(row)
        det = j00 * j11 - j01 * j10
        dcol = (j11 * du0 - j01 * du1) / det
        drow = (j00 * du1 - j10 * du0) / det
        err2 = dcol * dcol + drow * drow
        if not np.isnan(err2):
            total += err2
            count += 1
    return np.sqrt(total / count) if count else np.nan
