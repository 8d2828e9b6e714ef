"""Compiled inner loop of the oval-section fit (numba): a robust Levenberg-Marquardt
solve of the offset and the section for ring points whose tilt is held.

Why hand-written: ``pipestitch run`` refits every frame's section after each
refinement, on the main thread between two registration passes (1,440 fits at 1000
pairs). ``scipy.optimize.least_squares`` spends about a millisecond of Python on each
of these five-unknown problems, which this loop solves in tens of microseconds; it
finds the same minimum (the stationary point of the same soft-L1 cost), to a
tighter tolerance. The section's model and derivatives are those of
:func:`pipestitch.pose.section.oval_residuals` and ``oval_jacobian``.

How the compiled kernels are written and tested: docs/conventions.md, "Compiled kernels".
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

N_UNKNOWNS = 5         # dx, dy, r, c, s
MAX_ITERATIONS = 100
STEP_TOLERANCE = 1e-10   # a step this small relative to the unknowns' scale: converged
INITIAL_DAMPING, MIN_DAMPING, MAX_DAMPING = 1e-6, 1e-12, 1e12


@numba.njit(cache=True, nogil=True)
def fit_oval_offset(q0: np.ndarray, x0: np.ndarray, f_scale: float, x_scale: np.ndarray,
                    bounds: np.ndarray) -> tuple[np.ndarray, bool]:
    """The offset and section (dx, dy, r, c, s) minimising the soft-L1 cost of the radial
    residuals of the wall points ``q0 + (dx, dy)``.

    ``q0`` (N, 2): the ring points rotated by the held tilt, before the offset; ``x0``
    the start; ``f_scale`` the soft-L1 scale (the residuals' noise); ``x_scale`` the
    unknowns' typical sizes (the damping's scale); ``bounds`` (2, 5) the box the
    solution must lie strictly inside. Converged when a step is below
    ``STEP_TOLERANCE`` of the unknowns (or none lowers the cost). Returns (x,
    converged): not converged when the iterations ran out, a step left the box or the
    cost is not finite, for the caller to solve the problem with bounds instead.
    """
    x = x0.copy()
    cost = _cost(q0, x, f_scale)
    if not math.isfinite(cost):
        return x, False
    damping = INITIAL_DAMPING
    hessian = np.empty((N_UNKNOWNS, N_UNKNOWNS))
    gradient = np.empty(N_UNKNOWNS)
    for _ in range(MAX_ITERATIONS):
        _normal_equations(q0, x, f_scale, hessian, gradient)
        while True:
            step = _damped_step(hessian, gradient, damping, x_scale)
            if _negligible(step, x, x_scale):
                return x + step, _inside(x + step, bounds)
            trial = x + step
            trial_cost = _cost(q0, trial, f_scale)
            if trial_cost <= cost:
                damping = max(damping / 10, MIN_DAMPING)
                break
            damping *= 10
            if damping > MAX_DAMPING:   # no step lowers the cost: at its minimum
                return x, _inside(x, bounds)
        x, cost = trial, trial_cost
        if not _inside(x, bounds):
            return x, False
    return x, False


@numba.njit(cache=True, nogil=True)
def _negligible(step: np.ndarray, x: np.ndarray, x_scale: np.ndarray) -> bool:
    for k in range(N_UNKNOWNS):
        if not abs(step[k]) <= STEP_TOLERANCE * (abs(x[k]) + x_scale[k]):
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _inside(x: np.ndarray, bounds: np.ndarray) -> bool:
    for k in range(N_UNKNOWNS):
        if not bounds[0, k] < x[k] < bounds[1, k]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _residual(qx: float, qy: float, x: np.ndarray) -> tuple[float, float, float, float]:
    """A point's radial residual and what its derivatives need: (residual, n, root, k)
    with n = (1 + e²/4)|q|² - (c (qx² - qy²) + 2 s qx qy), root = sqrt(max(n, 0)) and
    k = 1 - e²/4 (the residual is root / k - r)."""
    c, s = x[3], x[4]
    e2 = c * c + s * s
    n = (1 + e2 / 4) * (qx * qx + qy * qy) - (c * (qx * qx - qy * qy) + 2 * s * qx * qy)
    root = math.sqrt(max(n, 0.0))
    k = 1 - e2 / 4
    return root / k - x[2], n, root, k


@numba.njit(cache=True, nogil=True)
def _cost(q0: np.ndarray, x: np.ndarray, f_scale: float) -> float:
    """The soft-L1 cost: sum of 2 f² (sqrt(1 + (res / f)²) - 1)."""
    total = 0.0
    for i in range(q0.shape[0]):
        res = _residual(q0[i, 0] + x[0], q0[i, 1] + x[1], x)[0]
        z = (res / f_scale) ** 2
        total += 2 * f_scale * f_scale * (math.sqrt(1 + z) - 1)
    return total


@numba.njit(cache=True, nogil=True)
def _normal_equations(q0: np.ndarray, x: np.ndarray, f_scale: float, hessian: np.ndarray,
                      gradient: np.ndarray) -> None:
    """The cost's gradient and Gauss-Newton Hessian (halved): with z = (res / f)², the
    soft-L1 loss rho(z) = 2 (sqrt(1 + z) - 1) weighs each point's gradient term by
    rho'(z) = (1 + z)^-1/2 and its Hessian term by rho'(z) + 2 z rho''(z) = (1 + z)^-3/2
    (the loss' own curvature: Newton's steps in the loss, quadratic convergence)."""
    c, s = x[3], x[4]
    e2 = c * c + s * s
    row = np.empty(N_UNKNOWNS)
    hessian[:] = 0.0
    gradient[:] = 0.0
    for i in range(q0.shape[0]):
        qx, qy = q0[i, 0] + x[0], q0[i, 1] + x[1]
        res, _, root, k = _residual(qx, qy, x)
        half = 1.0 / (2 * k * root) if root > 0 else 0.0
        sq, diff, cross = qx * qx + qy * qy, qx * qx - qy * qy, qx * qy
        row[0] = half * (2 * (1 + e2 / 4) * qx - 2 * (c * qx + s * qy))
        row[1] = half * (2 * (1 + e2 / 4) * qy + 2 * (c * qy - s * qx))
        row[2] = -1.0
        row[3] = half * (c / 2 * sq - diff) + root * c / (2 * k * k)
        row[4] = half * (s / 2 * sq - 2 * cross) + root * s / (2 * k * k)
        z1 = 1 + (res / f_scale) ** 2
        weight = 1.0 / math.sqrt(z1)
        curvature = weight / z1
        for a in range(N_UNKNOWNS):
            gradient[a] += weight * res * row[a]
            for b in range(N_UNKNOWNS):
                hessian[a, b] += curvature * row[a] * row[b]


@numba.njit(cache=True, nogil=True)
def _damped_step(hessian: np.ndarray, gradient: np.ndarray, damping: float,
                 x_scale: np.ndarray) -> np.ndarray:
    """Solve (H + damping · m · diag(1 / x_scale²)) step = -gradient by Cholesky (m: the
    mean of H's diagonal in the unknowns' scale); NaN when that is not positive definite."""
    m = 0.0
    for a in range(N_UNKNOWNS):
        m += hessian[a, a] * x_scale[a] * x_scale[a]
    m /= N_UNKNOWNS
    lower = np.zeros((N_UNKNOWNS, N_UNKNOWNS))
    for j in range(N_UNKNOWNS):
        d = hessian[j, j] + damping * m / (x_scale[j] * x_scale[j])
        for k in range(j):
            d -= lower[j, k] * lower[j, k]
        if not d > 0:
            return np.full(N_UNKNOWNS, np.nan)
        lower[j, j] = math.sqrt(d)
        for i in range(j + 1, N_UNKNOWNS):
            v = hessian[i, j]
            for k in range(j):
                v -= lower[i, k] * lower[j, k]
            lower[i, j] = v / lower[j, j]
    step = np.empty(N_UNKNOWNS)
    for i in range(N_UNKNOWNS):   # L y = -g
        v = -gradient[i]
        for k in range(i):
            v -= lower[i, k] * step[k]
        step[i] = v / lower[i, i]
    for i in range(N_UNKNOWNS - 1, -1, -1):   # L^T step = y
        v = step[i]
        for k in range(i + 1, N_UNKNOWNS):
            v -= lower[k, i] * step[k]
        step[i] = v / lower[i, i]
    return step
