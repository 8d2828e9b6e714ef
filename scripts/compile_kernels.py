"""Compile pipestitch's numba kernels ahead of the first run, into numba's on-disk cache.

``scripts/setup-env.sh`` runs this after installing, so that the first ``pipestitch
run`` loads the compiled kernels (about 1 s) instead of compiling them (about a
minute on 2 cores). Each kernel that Python code calls is compiled for the one
signature a run calls it with (:data:`KERNELS`); the kernels it calls are compiled with
it. A pool of processes takes the entries in list order, each as a process comes free.
The pose fit's tree is most of the work, so its two independent halves come first
(its refinement and its ring selection, compiled at once by two processes) and its
entry after them (:data:`WAITS_FOR`): numba then loads the halves from the cache
instead of compiling them again. Numba compiles each kernel (with the code of every
kernel it calls) into its own machine code, so a kernel that only one other calls, as
a step of it, is inlined into it (``inline="always"``) rather than compiled twice.

``tests/test_kernel_warmup.py`` checks that a run after this compiles nothing new: a
kernel whose signature changes must change here too.

Usage: ``python scripts/compile_kernels.py [--jobs N] [--stamp FILE]``. With
``--stamp``, nothing is done when FILE holds the key of the current kernel sources,
numba version, cache folder and the processor the kernels are compiled for (and FILE
is written after a successful compile).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import multiprocessing
import os
import re
import sys
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "pipestitch"

# (module, kernel, argument types). Types: f4 f8 i8 i2 u1 u2 b1 are float32, float64,
# int64, int16, uint8, uint16 and bool scalars; "f4:2" is a C-contiguous 2-d float32
# array, a trailing "A" any layout, a trailing "r" read-only; "Name(f8 i8)" a named
# tuple of the kernel's module (its class ``Name``) with fields of those types.
PLANE = "Plane(f8 f8:1r f8:2r)"
FIT_SETTINGS = "FitSettings(f8 f8 i8 f8 i8 i8)"
KERNELS: tuple[tuple[str, str, str], ...] = (
    # the fit's two halves as fit_frame calls them, then the fit (see WAITS_FOR)
    ("pose._fit_kernels", "refine_frame", f"f8:1 f8:2 b1:1 i8 {PLANE} {FIT_SETTINGS}"),
    ("pose._fit_kernels", "select_ring",
     f"f8:2 Candidates(f8:2 i8:1A i8:1A i8) {PLANE} {FIT_SETTINGS} f8:2"),
    ("pose._fit_kernels", "fit_fields",   # Candidates, RayKernel, Plane, FitSettings
     "f8:2 i8:1A i8:1A i8 i8 f8:1 f8:1 f8:1 f8:1 i8:1 f8 f8:1r f8:2r f8 f8 i8 f8 i8 i8 f8 f8:2"),
    ("pose._fit_kernels", "rays_to_plane", f"f8:2 {PLANE}"),
    ("pose._pair_motion_kernels", "sector_correlations",
     "f4:2 i8 i8 i8:2 i8:1 i8:1 f8:1 f8:1 i8:1 i8 i8"),
    ("pose._ring_kernels", "flatten_by_reflectance", "f4:2 f4:2 i8 f8 f8"),
    ("pose._ring_kernels", "flatten_by_moved_reflectance", "f4:2 f4:2 f8:1 f8:1 i8 f8 f8"),
    ("pose._ring_kernels", "ridge_peaks", "f4:2 f8 i8"),
    ("pose._ring_kernels", "line_widths", "f4:2 i8:1 i8:1 i8"),
    ("pose._ring_kernels", "centroids", "f4:2 f4:2 i8:1 i8:1 i8 f8:1"),
    ("pose._section_kernels", "fit_oval_offset", "f8:2 f8:1 f8 f8:1 f8:2"),
    ("camera.kernels", "rays_of", "RayKernel(i8 f8:1 f8:1 f8:1 f8:1 i8:1) f8:2"),
    ("camera.ocam", "_rho_of_points", "f8:2 f8:1 f8:1 f8:1 f8:1 i8:1"),
    ("camera.ocam", "_pixels", "f8:2 f8:1 f8:1"),
    ("camera.ocam", "ray_loop", "f8:2 f8:1 f8:1 f8"),
    ("mosaic._unwrap_kernels", "upsample_masked", "f4:3 i8 i8 i8 f8"),
    ("mosaic._unwrap_kernels", "node_points", "f8:2 f8:1 f8:1 f8:1 f8:1"),
    ("mosaic._unwrap_kernels", "node_fields", "f8:2 i8 i8 i8 b1 f8:2 f8:2 f8:1 f8:1 f8:1 f8"),
    ("mosaic._unwrap_kernels", "mask_strip", "f4:2 f4:2 f4:2 f4:2 f8 u1:2 i8"),
    ("mosaic._unwrap_kernels", "fill_invalid", "f4:2"),
    ("mosaic._unwrap_kernels", "contrast_of", "f4:2 f4:2 f4:2 f4:2"),
    ("mosaic._noise_kernels", "contrast_fields", "f4:2 f4:2 f4:2 f8 f8 i8"),
    ("mosaic._occluder_kernels", "quantile_over_frames", "f4:3 f8 b1"),
    ("mosaic._occluder_kernels", "variance_over_frames", "f4:3 i8"),
    ("mosaic._register_kernels", "cross_power_ccs", "f4:2 f4:2"),
    ("mosaic._register_kernels", "weighted_peak", "f4:2 f4:1 f4:1 f8"),
    ("mosaic._register_kernels", "gradient_moments", "f4:2 f4:2"),
    ("mosaic._register_kernels", "patches_valid", "b1:2 b1:2 i8 i8 i8 i8"),
    ("mosaic._register_kernels", "link_patches", "f4:2 f4:2 b1:2 i8 i8 i8 f4:2 f8 f8"),
    ("mosaic._register_kernels", "polish_patches", "f4:3 f4:3 f4:2 f8:2 i8 f8:2 f8"),
    ("mosaic._register_kernels", "polish", "f4:2 f4:2 f4:2 f8 f8 i8 f8:1 f8 f8 f8 f8"),
    ("mosaic._register_kernels", "minus_weighted_mean", "f4:2 f4:1 f8"),
    ("mosaic._register_kernels", "tapered_image", "f4:2 f4:2 f4:1"),
    ("mosaic._photometric_kernels", "contrast_and_dark", "f4:2 f4:2 f4:2 f4:2 f4"),
    ("mosaic._photometric_kernels", "masked_contrast", "f4:2 u1:2 f4:2"),
    ("mosaic._photometric_kernels", "ccs_modulus", "f4:2"),
    ("mosaic._blend_kernels", "shaded_albedo", "f4:2 f4:2 f4:2"),
    ("mosaic._flat_field_kernels", "fall_off_at", "f4:2 f4:2 f8 f8 f8 f8:1 f4:2"),
    ("mosaic._flat_field_kernels", "ring_index", "f4:2 f4:2 f8 f8 f8 i8"),
    ("mosaic._flat_field_kernels", "pair_cells", "i2:2 f4:2 i2:2 f4:2 i8 i8 i8"),
    ("mosaic._flat_field_kernels", "group_medians", "i8:1 f4:1"),
    ("mosaic._blend_kernels", "feathered_weight", "f4:2 f4:2 u1:2 i8"),
    ("mosaic._blend_kernels", "accumulate_strip", "f4:2 f4:2 i8 f4:2 f4:2 f8"),
    ("mosaic._blend_kernels", "gain_ratios", "f4:2 f4:2 i8 f4:2 f4:2 i8 f4:1"),
    ("io._image_kernels", "scaled_uint8", "f4:2 f8"),
    ("imaging.medians", "_middle_ranks", "f4:1 b1"),
    ("imaging.medians", "_middle_ranks", "f4:1r b1"),   # a read-only array's own values
    # laser frames as decoded, LED frames as the run's cache shares them (read-only)
    ("imaging.scaling", "_scaled", "u1:2 f4 f4:2"),
    ("imaging.scaling", "_scaled", "u1:2r f4 f4:2"),
    ("imaging.scaling", "_scaled", "u2:2 f4 f4:2"),
    ("imaging.scaling", "_scaled", "u2:2r f4 f4:2"),
    ("io._image_kernels", "png_unfilter", "u1:1r i8 i8 i8 u1:1"),
    ("io._image_kernels", "png_paeth_filter", "u1:2r i8"),
)
# An entry that calls others compiles after them, so that it loads them from the cache.
WAITS_FOR: dict[tuple[str, str], tuple[tuple[str, str], ...]] = {
    ("pose._fit_kernels", "fit_fields"): (("pose._fit_kernels", "refine_frame"),
                                          ("pose._fit_kernels", "select_ring")),
}


def parse_types(text: str, namespace: object = None) -> tuple:
    """Numba argument types of a :data:`KERNELS` entry's type string.

    Parameters
    ----------
    text : str
        Space-separated types, e.g. ``"f4:2 f8 i8:1A f8:1r Plane(f8 f8:1r f8:2r)"``.
    namespace : module, optional
        Where the named tuples' classes are looked up (the kernel's module); needed only
        when ``text`` names one.

    Returns
    -------
    tuple of numba.core.types.Type
        The argument types, in order.
    """
    from numba.core import types

    out = []
    for struct, fields, token in re.findall(r"(\w+)\(([^()]*)\)|(\S+)", text):
        if not struct:
            out.append(_scalar_or_array(token))
            continue
        members = [_scalar_or_array(t) for t in fields.split()]
        out.append(types.BaseTuple.from_types(members, getattr(namespace, struct)))
    return tuple(out)


def _scalar_or_array(token: str) -> object:
    """Numba type of one token of a type string (:func:`parse_types`), e.g. ``"f4:2A"``."""
    from numba.core import types

    scalars = {"f4": types.float32, "f8": types.float64, "i8": types.int64,
               "i2": types.int16, "u1": types.uint8, "u2": types.uint16,
               "b1": types.boolean}
    name, _, rest = token.partition(":")
    if not rest:
        return scalars[name]
    layout = "A" if "A" in rest else "C"
    return types.Array(scalars[name], int(rest.rstrip("Ar")), layout, readonly="r" in rest)


def next_entry(pending: list[int], done: set[int]) -> int | None:
    """The first of ``pending`` (indices into :data:`KERNELS`, in compile order) whose
    entries in :data:`WAITS_FOR` are all ``done``; None when each still waits.

    Parameters
    ----------
    pending : list of int
        Entries not yet started.
    done : set of int
        Entries compiled.

    Returns
    -------
    int or None
        The entry to start next.
    """
    index = {entry[:2]: i for i, entry in enumerate(KERNELS)}
    for i in pending:
        if all(index[key] in done for key in WAITS_FOR.get(KERNELS[i][:2], ())):
            return i
    return None


def compile_entries(indices: list[int]) -> float:
    """Compile the given :data:`KERNELS` entries in this process (or load them from the
    cache); return the seconds it took.

    Parameters
    ----------
    indices : list of int
        Entries of :data:`KERNELS`.

    Returns
    -------
    float
        Wall time, s.
    """
    t0 = time.perf_counter()
    for i in indices:
        module, name, sig = KERNELS[i]
        namespace = importlib.import_module(f"pipestitch.{module}")
        getattr(namespace, name).compile(parse_types(sig, namespace))
    return time.perf_counter() - t0


def source_key() -> str:
    """Key of what the compiled cache depends on: the stamp numba's cache of the kernels
    carries (:func:`pipestitch._runtime.kernel_sources.sources_stamp`: every file kernel
    code comes from), this file, the interpreter, numba's version, the cache folder and
    the processor the kernels are compiled for
    (:func:`pipestitch._runtime.kernel_cache.compile_target`: the same on every machine
    of an x86-64 level, v4 or v3; the machine's own elsewhere).

    Returns
    -------
    str
        A hex digest.
    """
    from importlib.metadata import version

    from pipestitch._runtime.kernel_cache import compile_target
    from pipestitch._runtime.kernel_sources import sources_stamp

    h = hashlib.sha256(Path(__file__).read_bytes())
    h.update(f"{sources_stamp()}|{sys.executable}|{version('numba')}|"
             f"{os.environ.get('NUMBA_CACHE_DIR', '')}|{compile_target()}".encode())
    return h.hexdigest()


def clear_cache() -> int:
    """Delete pipestitch's kernels from numba's on-disk cache; return how many files.

    Every cached kernel of the package carries the stamp of all the kernel sources
    (:mod:`pipestitch._runtime.kernel_cache`), so after a change to any of them numba
    loads none of the old ones; a compile still starts from an empty cache so that the
    files of a kernel renamed or removed, and of the old stamps, do not stay behind.
    Each module's kernels are looked for where numba keeps them: under
    ``NUMBA_CACHE_DIR`` when that is set, else in the ``__pycache__`` beside the source
    when it is writable, else in the user's numba cache folder (numba's own sub-folder
    for each source folder).
    """
    from numba.core.caching import _CacheLocator
    from numba.misc.appdirs import AppDirs

    user = os.environ.get("NUMBA_CACHE_DIR")
    removed = 0
    for source in SRC.rglob("*.py"):
        beside = source.parent / "__pycache__"
        if user:
            place = Path(user) / _CacheLocator.get_suitable_cache_subpath(str(source))
        elif os.access(source.parent, os.W_OK) and (not beside.exists()
                                                     or os.access(beside, os.W_OK)):
            place = beside
        else:
            place = (Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)
                     / _CacheLocator.get_suitable_cache_subpath(str(source)))
        for f in [*place.glob(f"{source.stem}.*.nbi"), *place.glob(f"{source.stem}.*.nbc")]:
            f.unlink(missing_ok=True)
            removed += 1
    return removed


def compile_all(n_jobs: int, verbose: bool = False) -> int:
    """Compile every :data:`KERNELS` entry in a pool of processes; return how many failed.

    Each process that comes free takes the next entry :func:`next_entry` allows. A
    failed entry counts as done: a kernel that calls it compiles it itself.

    Parameters
    ----------
    n_jobs : int
        Processes.
    verbose : bool
        Print each entry's time and process.

    Returns
    -------
    int
        Entries not compiled.
    """
    pending, done, failed = list(range(len(KERNELS))), set(), 0
    running: dict[Future, int] = {}
    try:
        with ProcessPoolExecutor(n_jobs,
                                 mp_context=multiprocessing.get_context("spawn")) as pool:
            while pending or running:
                while len(running) < n_jobs and (i := next_entry(pending, done)) is not None:
                    pending.remove(i)
                    running[pool.submit(_compile_one, i)] = i
                if not running:   # only if WAITS_FOR named an entry that never starts
                    break
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in finished:
                    i = running.pop(future)
                    done.add(i)
                    try:
                        seconds, pid = future.result()
                    except BrokenProcessPool:
                        raise
                    except Exception as error:   # reported; compiled on first use
                        failed += 1
                        print(f"compile_kernels: {KERNELS[i][1]}: "
                              f"{type(error).__name__}: {error}", file=sys.stderr)
                        continue
                    if verbose:
                        print(f"  {seconds:5.1f} s  process {pid}: {KERNELS[i][1]}",
                              file=sys.stderr)
    except BrokenProcessPool as error:   # a process died (e.g. out of memory)
        print(f"compile_kernels: {error}", file=sys.stderr)
        return failed + 1 + len(running) + len(pending)
    return failed + len(pending)


def import_kernel_modules() -> None:
    """Import every module of :data:`KERNELS` in this process before the pool starts.

    Where bytecode may be written (the set-up runs this script so), this writes that of
    the modules and of what they import (numba, numpy, ...) once, and the pool's
    processes, each importing the same, read it instead of compiling every module again.
    A module that fails to import is left to the pool, which reports its entries.
    """
    for module in dict.fromkeys(module for module, _, _ in KERNELS):
        try:
            importlib.import_module(f"pipestitch.{module}")
        except Exception:   # reported with the entries that need it
            continue


def _compile_one(i: int) -> tuple[float, int]:
    """(seconds, process id) of compiling :data:`KERNELS` entry ``i`` in a pool process."""
    return compile_entries([i]), os.getpid()


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 when every kernel compiled.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes (default: 2, or 1 on one core)")
    parser.add_argument("--stamp", type=Path, help="skip when this file holds the key")
    parser.add_argument("--verbose", action="store_true", help="each kernel's time")
    args = parser.parse_args(argv)
    key = source_key()
    if args.stamp is not None and args.stamp.is_file() and args.stamp.read_text() == key:
        return 0
    t0 = time.perf_counter()
    clear_cache()   # nothing of the old sources' kernels stays behind
    jobs = max(1, args.jobs)
    print(f"compiling the numba kernels ({jobs} processes, once: up to a minute) ...",
          file=sys.stderr)
    import_kernel_modules()
    failed = compile_all(jobs, args.verbose)
    if failed:
        print(f"compile_kernels: {failed} of {len(KERNELS)} kernels failed; they will "
              "compile on first use", file=sys.stderr)
        return 1
    print(f"compiled {len(KERNELS)} kernels in {time.perf_counter() - t0:.1f} s "
          f"({jobs} processes)", file=sys.stderr)
    if args.stamp is not None:
        args.stamp.write_text(key)
    return 0


if __name__ == "__main__":
    sys.exit(main())
