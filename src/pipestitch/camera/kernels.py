"""The camera models' compiled unprojection behind one signature, for fused kernels.

A compiled algorithm that needs rays of pixels it computes itself (the pose fit:
which pixels it unprojects depends on the ring candidates) would otherwise return to
Python for :meth:`CameraModel.unproject` and enter a second kernel afterwards. Right
after a ring extraction each such entry is cold and costs more than its arithmetic
(measured: ~50 µs a frame of a ~450 µs pose fit). Numba cannot take the models'
kernels as arguments without losing its on-disk cache or paying a Python-level call
(~50 µs) each time, so the models describe their kernel as data instead: a
:class:`~pipestitch.camera.base.RayKernel` (which model, its parameter arrays) that
:func:`rays_of` turns into rays inside compiled code. A model without one simply has
no ``ray_kernel``; callers then use ``unproject``.

The cached callers (``pose._fit_kernels.fit_fields`` calls a model's ``ray_loop``
through :func:`rays_of`) hold the loop's code: an edit of it must reach them, which
the package's cache stamp sees to (:mod:`pipestitch._runtime.kernel_cache`).
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)
from pipestitch.camera import ocam, opencv_fisheye
from pipestitch.camera.base import OCAM, OPENCV_FISHEYE, RayKernel

__all__ = ["rays_of"]


# error_model set, as the fit that calls it sets its own (docs/conventions.md, "Compiled
# kernels"): a division by zero gives inf, never an exception, whoever calls it
@numba.njit(cache=True, nogil=True, error_model="numpy")
def rays_of(camera: RayKernel, pixels: np.ndarray) -> np.ndarray:
    """Unit rays of pixels through the model a RayKernel names.

    Exactly the model's ``unproject`` (the same compiled loop).

    Parameters
    ----------
    camera : RayKernel
        The model's ``ray_kernel``.
    pixels : numpy.ndarray, shape (N, 2), float64, C-contiguous
        Pixels (col, row).

    Returns
    -------
    numpy.ndarray, shape (N, 3)
        Unit rays; NaN outside the model's valid range.
    """
    if camera.kind == OCAM:
        return ocam.ray_loop(pixels, camera.a, camera.b, camera.c[0])
    if camera.kind == OPENCV_FISHEYE:
        return opencv_fisheye.ray_loop(pixels, camera.a, camera.b, camera.c, camera.d,
                                       camera.index)
    raise ValueError("rays_of: unknown RayKernel kind")
