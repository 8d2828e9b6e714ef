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

Its kernels are saved safely when several processes save kernels of one function at
once (:func:`_save`: numba's own numbering of the data files is not).

Importing it also chooses the processor numba compiles for (:func:`pin_portable_target`):
on x86-64 the best of the psABI's levels x86-64-v4 (AVX-512) and x86-64-v3 (AVX2, FMA)
that the processor runs, rather than the processor itself, so that the cache the set-up
fills serves any machine of that level (a container image built on another model, a
worker on another kind of node), where numba would otherwise compile every kernel again
on first use.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import platform
from collections.abc import Iterator, Mapping

try:
    import fcntl
except ImportError:   # not POSIX: no lock (each entry's file still holds its own code)
    fcntl = None

import llvmlite.binding as llvm
from numba.core import caching, config, registry

from pipestitch._runtime.kernel_sources import PACKAGE, sources_stamp

__all__ = ["LOCATORS", "PORTABLE_CPUS", "compile_target", "in_package", "level_features",
           "pin_portable_target", "portable_cpu"]


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


# numba's own save (below: this package's kernels are saved by _save instead)
_NUMBA_SAVE = caching.IndexDataCacheFile.save
LOCK_NAME = "pipestitch-kernels.lock"   # beside the cached kernels, while one is saved


def _save(self: caching.IndexDataCacheFile, key: tuple, data: object) -> None:
    """``IndexDataCacheFile.save`` for this package's kernels: safe when several
    processes save kernels of one function at once (the set-up's pool, a batch's
    workers, two runs).

    numba numbers a function's data files in the order its index lists them, reading
    the index, then writing it and the data file: two processes that read the index
    before either wrote it take the same number, and the index can end up naming one
    signature's file with another signature's code (a set-up's pool left the read-only
    8-bit frames' scaling holding the 16-bit one's, and every frame of every run then
    failed to unbox its array). Here a data file is named by its key's digest, written
    before the index names it, and the index is read and written under a lock on the
    folder; numba's own save serves every other function.
    """
    if self._source_stamp != sources_stamp():
        _NUMBA_SAVE(self, key, data)
        return
    # the stamp and numba's version too: processes of other sources sharing the folder
    # never write each other's files
    digest = hashlib.sha256(repr((self._source_stamp, self._version, key)).encode()
                            ).hexdigest()[:20]
    name = f"{self._index_name[:-len('.nbi')]}.{digest}.nbc"
    with _locked(self._cache_path):
        self._save_data(name, data)
        overloads = self._load_index()
        if overloads.get(key) != name:
            overloads[key] = name
            self._save_index(overloads)


@contextlib.contextmanager
def _locked(folder: str) -> Iterator[None]:
    """An exclusive lock on ``folder`` (its file ``LOCK_NAME``) across processes, where
    the system has ``fcntl`` and the lock can be taken (else none: concurrent saves may
    then lose an index entry, compiled again later, never file wrong code); released
    when the file is closed."""
    handle = None
    if fcntl is not None:
        try:
            handle = open(os.path.join(folder, LOCK_NAME), "a")   # closed below
            fcntl.flock(handle, fcntl.LOCK_EX)
        except OSError:   # another user's lock file, a file system without locks
            if handle is not None:
                handle.close()
            handle = None
    try:
        yield
    finally:
        if handle is not None:
            handle.close()


# The processors the kernels are compiled for, best first, where the machine runs their
# code: the psABI's levels (LLVM's names) and the features each needs (LLVM's names).
# x86-64-v3: AVX2, FMA, BMI1/2, F16C, LZCNT, MOVBE, XSAVE over SSE4.2, POPCNT, CMPXCHG16B
# (Intel's Core and Xeon since 2013, AMD since 2015); x86-64-v4: AVX-512 F, BW, CD, DQ
# and VL over it.
# On an AVX-512 Xeon v4 code fitted a pose as fast as code for the Xeon itself, v3 code
# ~6 % slower; 60-pair runs took the same time and gave every output the same
# (docs/benchmarks.md).
LEVEL_3 = ("cmov", "cx8", "fxsr", "mmx", "sse", "sse2", "sse3", "ssse3", "sse4.1", "sse4.2",
           "popcnt", "cx16", "sahf", "avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt",
           "movbe", "xsave")
LEVEL_4 = (*LEVEL_3, "avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl")
PORTABLE_CPUS = (("x86-64-v4", LEVEL_4), ("x86-64-v3", LEVEL_3))


def portable_cpu(machine: str, features: Mapping[str, bool]) -> str | None:
    """The best of :data:`PORTABLE_CPUS` whose code a processor runs; None when it runs
    neither's (not x86-64, or older than level 3).

    Parameters
    ----------
    machine : str
        ``platform.machine()``.
    features : mapping of str to bool
        The processor's features as LLVM names them (``llvmlite.binding.
        get_host_cpu_features()``: what the processor and the operating system enable).

    Returns
    -------
    str or None
        LLVM's name of the level.
    """
    if machine.lower() not in ("x86_64", "amd64"):
        return None
    for name, needed in PORTABLE_CPUS:
        if all(features.get(feature, False) for feature in needed):
            return name
    return None


def level_features(name: str) -> str:
    """The features of a level of :data:`PORTABLE_CPUS`, as ``NUMBA_CPU_FEATURES`` takes
    them (``+avx2,+fma,...``)."""
    return ",".join(f"+{feature}" for feature in dict(PORTABLE_CPUS)[name])


def pin_portable_target() -> bool:
    """Make numba compile for :func:`portable_cpu`'s level (``NUMBA_CPU_NAME`` and
    ``NUMBA_CPU_FEATURES``: :func:`level_features`) where the processor has one; True
    when it does.

    numba keys each cached kernel by the processor's name and every feature it has, so
    a kernel compiled on one model is compiled again on any other (a minute of the
    first run); compiled for a level, it serves every processor of that level. The
    features are spelled out (they are the level's anyway): numba reads the name in
    its key afresh, the features as its compiler was made, so a name changed inside a
    running process cannot file one level's code under another's key. Nothing is
    changed where the user chose numba's processor (``NUMBA_CPU_NAME`` or
    ``NUMBA_CPU_FEATURES``, in the environment or numba's configuration file; e.g.
    ``NUMBA_CPU_NAME=x86-64-v3`` with ``NUMBA_CPU_FEATURES=`` followed by
    :func:`level_features` of it, at the set-up and in every run, shares one cache
    between AVX2 and AVX-512 machines) or turned AVX off (``NUMBA_ENABLE_AVX=0``), when
    numba of this process already compiles for the processor itself (its compiler is
    made once, at the first kernel: a kernel of this package compiled then is cached
    for that processor, as without this), or on a processor of neither level (not
    x86-64, or older).
    """
    if config.CPU_NAME is not None or config.CPU_FEATURES is not None or not config.ENABLE_AVX:
        return False
    if "_toplevel_target_context" in vars(registry.cpu_target):
        return False
    try:
        features = llvm.get_host_cpu_features()
    except RuntimeError:   # LLVM cannot tell on this system
        return False
    name = portable_cpu(platform.machine(), features)
    if name is None:
        return False
    os.environ["NUMBA_CPU_NAME"], os.environ["NUMBA_CPU_FEATURES"] = name, level_features(name)
    config.reload_config()
    return True


def compile_target() -> tuple[str, str, str]:
    """(platform, processor, features) numba compiles this process' kernels for: the
    part of each cached kernel's key that names the machine (numba's own
    ``magic_tuple``; it makes numba's compiler if none was made yet)."""
    return registry.cpu_target.target_context.codegen().magic_tuple()


def _register() -> None:
    classes = caching.CacheImpl._locator_classes
    for cls in reversed(LOCATORS):
        if cls not in classes:
            classes.insert(0, cls)
    caching.IndexDataCacheFile.save = _save


_register()
pin_portable_target()
