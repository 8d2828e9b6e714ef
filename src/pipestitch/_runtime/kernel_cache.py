"""numba's on-disk cache of the package's kernels, stamped by all their sources at once.

numba keeps a compiled kernel with a stamp of its own source file (a hash of it) and
reuses it while that file is unchanged. A kernel's compiled code also holds the code
of every kernel it calls, and the constants it reads, from other files: after a change
to a callee's file (a ``git pull``, an upgrade of the package in place, which leaves
the cache files beside the sources) numba would still load the caller with the old
callee compiled into it, and a run would compute with code that is no longer there.

Importing this module puts locators in front of numba's own (the same three places,
in numba's order: ``NUMBA_CACHE_DIR``, ``__pycache__`` beside the source, the user's
cache folder) that stamp every kernel of this package with one hash of all the files
kernel code comes from (:mod:`pipestitch._runtime.kernel_sources`): a change to any of
them invalidates every cached kernel of the package, and the next run or set-up
compiles them again. Each module that defines kernels imports this one before its
first ``numba.njit`` (``tests/_runtime/test_kernel_cache.py`` checks it, and that the
list of sources is whole). ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, replaces
numba's list, and this one, with its own.
"""

from __future__ import annotations

import os

from numba.core import caching

from pipestitch._runtime.kernel_sources import PACKAGE, sources_stamp

__all__ = ["LOCATORS", "in_package"]


def in_package(py_file: str) -> bool:
    """Whether ``py_file`` is a source of this package."""
    return os.path.realpath(py_file).startswith(PACKAGE + os.sep)


class _PackageStamp:
    """A numba locator, for this package's files only, stamped by :func:`sources_stamp`."""

    def get_source_stamp(self) -> str:
        return sources_stamp()

    @classmethod
    def from_function(cls, py_func: object, py_file: str) -> caching._CacheLocator | None:
        if not in_package(py_file):
            return None   # numba's own locators take it
        return super().from_function(py_func, py_file)


class PackageUserProvidedLocator(_PackageStamp, caching.UserProvidedCacheLocator):
    """Under ``NUMBA_CACHE_DIR``, when set."""


class PackageInTreeLocator(_PackageStamp, caching.InTreeCacheLocator):
    """In the ``__pycache__`` beside the source, when writable."""


class PackageUserWideLocator(_PackageStamp, caching.UserWideCacheLocator):
    """In the user's numba cache folder."""


LOCATORS = (PackageUserProvidedLocator, PackageInTreeLocator, PackageUserWideLocator)


def _register() -> None:
    classes = caching.CacheImpl._locator_classes
    for cls in reversed(LOCATORS):
        if cls not in classes:
            classes.insert(0, cls)


_register()
