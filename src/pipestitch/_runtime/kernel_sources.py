"""The files a compiled kernel's code can come from, and one stamp of them all.

:mod:`pipestitch._runtime.kernel_cache` stamps every cached kernel of the package with
:func:`sources_stamp`, and ``scripts/compile_kernels.py`` compiles them again when it
changes; this module imports no numba, so that the set-up's check stays quick.
"""

from __future__ import annotations

import functools
import hashlib
import os

__all__ = ["KERNEL_SOURCES", "PACKAGE", "sources_stamp"]

PACKAGE = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))

# Every file, relative to the package, whose text can end up in a kernel's compiled
# code: the modules that define kernels and the modules they import names from; and
# the module that saves and keys the cache (a change to how kernels are saved or which
# processor they are compiled for re-stamps every cached kernel, so that none saved
# the old way is loaded).
KERNEL_SOURCES = (
    "_runtime/kernel_cache.py",
    "camera/base.py",
    "camera/kernels.py",
    "camera/ocam.py",
    "camera/opencv_fisheye.py",
    "imaging/medians.py",
    "imaging/scaling.py",
    "io/_image_kernels.py",
    "mosaic/_blend_kernels.py",
    "mosaic/_flat_field_kernels.py",
    "mosaic/_noise_kernels.py",
    "mosaic/_occluder_kernels.py",
    "mosaic/_photometric_kernels.py",
    "mosaic/_register_kernels.py",
    "mosaic/_unwrap_kernels.py",
    "pose/_fit_kernels.py",
    "pose/_pair_motion_kernels.py",
    "pose/_ring_kernels.py",
    "pose/_section_kernels.py",
)


@functools.cache
def sources_stamp() -> str:
    """The hash of every file of :data:`KERNEL_SOURCES` (name and bytes), read once a
    process.

    Returns
    -------
    str
        A hex digest.
    """
    digest = hashlib.sha256()
    for name in KERNEL_SOURCES:
        with open(os.path.join(PACKAGE, name), "rb") as f:
            digest.update(f"{name}\n".encode())
            digest.update(f.read())
    return digest.hexdigest()
