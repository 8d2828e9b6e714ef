"""Every cached kernel carries one stamp of all the kernel sources (_runtime/kernel_cache)."""

from __future__ import annotations

import ast
import importlib
import platform
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numba.core.registry
import pytest
from numba.core import caching

from pipestitch._runtime import kernel_cache, kernel_sources

SRC = Path(kernel_sources.PACKAGE)


KERNEL = re.compile(r"^@numba\.njit", re.MULTILINE)


def _kernel_modules() -> list[Path]:
    return sorted(p for p in SRC.rglob("*.py") if KERNEL.search(p.read_text()))


def _name(path: Path) -> str:
    return path.relative_to(SRC).as_posix()


def _package_imports(path: Path) -> set[str]:
    """The package's files ``path`` takes names from (a module's own file for
    ``from pipestitch.camera import ocam``)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if not (isinstance(node, ast.ImportFrom) and node.module
                and node.module.startswith("pipestitch.")):
            continue
        base = SRC.joinpath(*node.module.split(".")[1:])
        for alias in node.names:
            if (base / f"{alias.name}.py").is_file():
                out.add(_name(base / f"{alias.name}.py"))
            elif base.with_suffix(".py").is_file():
                out.add(_name(base.with_suffix(".py")))
            else:
                out.add(_name(base / "__init__.py"))
    return out


def test_the_sources_are_every_file_kernel_code_comes_from() -> None:
    modules = _kernel_modules()
    assert modules, "no kernel module found"
    listed = set(kernel_sources.KERNEL_SOURCES)
    assert {_name(m) for m in modules} <= listed
    runtime = {"_runtime/kernel_cache.py", "_runtime/__init__.py"}   # no kernel code
    for module in modules:
        missing = _package_imports(module) - listed - runtime
        assert not missing, f"{_name(module)} takes names from {missing}"
    assert all((SRC / name).is_file() for name in listed)


def test_every_kernel_module_imports_the_cache_before_its_first_kernel() -> None:
    for module in _kernel_modules():
        text = module.read_text()
        at = text.find("from pipestitch._runtime import kernel_cache")
        assert 0 <= at < KERNEL.search(text).start(), _name(module)


def test_every_cached_kernel_is_stamped_by_all_the_sources() -> None:
    found = 0
    for module in _kernel_modules():
        name = "pipestitch." + ".".join(module.relative_to(SRC).with_suffix("").parts)
        for obj in vars(importlib.import_module(name)).values():
            if isinstance(obj, numba.core.registry.CPUDispatcher) and obj._cache is not None:
                cache = obj._cache
                if type(cache).__name__ == "NullCache":
                    continue
                found += 1
                assert type(cache._impl.locator) in kernel_cache.LOCATORS, obj
                assert cache._cache_file._source_stamp == kernel_sources.sources_stamp(), obj
    assert found > 40


def test_the_stamp_changes_with_any_source(tmp_path: Path, monkeypatch) -> None:
    for name in ("a.py", "b.py"):
        (tmp_path / name).write_text(f"# {name}\n")
    monkeypatch.setattr(kernel_sources, "PACKAGE", str(tmp_path))
    monkeypatch.setattr(kernel_sources, "KERNEL_SOURCES", ("a.py", "b.py"))
    stamps = []
    for change in (None, "a.py", "b.py"):
        if change:
            (tmp_path / change).write_text("changed\n")
        kernel_sources.sources_stamp.cache_clear()
        stamps.append(kernel_sources.sources_stamp())
    kernel_sources.sources_stamp.cache_clear()
    assert len(set(stamps)) == 3


# A child interpreter with a package of two kernel files in ``root``: ``b.f`` calls
# ``a.g``, each cached by numba beside its source; prints ``f(1)``.
CHILD = textwrap.dedent("""
    import os, sys
    from pipestitch._runtime import kernel_cache, kernel_sources
    root = os.path.realpath(sys.argv[1])
    kernel_sources.PACKAGE = kernel_cache.PACKAGE = root
    kernel_sources.KERNEL_SOURCES = ("a.py", "b.py")
    sys.path.insert(0, root)
    import b
    print(b.f(1))
""")
CALLEE = textwrap.dedent("""
    import numba
    from pipestitch._runtime import kernel_cache  # noqa: F401

    @numba.njit(cache=True)
    def g(x):
        return x + {step}
""")
CALLER = textwrap.dedent("""
    import numba
    from pipestitch._runtime import kernel_cache  # noqa: F401
    from a import g

    @numba.njit(cache=True)
    def f(x):
        return 10 * g(x)
""")


def test_a_caller_is_compiled_again_when_its_callee_changes(tmp_path: Path,
                                                             monkeypatch) -> None:
    # numba alone would load b.f from its cache (b.py is unchanged) with the old a.g
    # compiled into it, and print 20 twice.
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    (tmp_path / "b.py").write_text(CALLER)
    printed = []
    for step in (1, 2):
        (tmp_path / "a.py").write_text(CALLEE.format(step=step))
        proc = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path)],
                              capture_output=True, text=True, timeout=300, check=False)
        assert proc.returncode == 0, proc.stderr[-2000:]
        printed.append(int(proc.stdout.split()[-1]))
    assert list((tmp_path / "__pycache__").glob("b.f-*.nbc")), "b.f was not cached"
    assert printed == [20, 30]


# A child interpreter: its environment's NUMBA_* as given, optionally a kernel of its
# own compiled first; prints the (platform, processor, features) numba keys kernels by
# after the package's kernel cache is imported.
TARGET = textwrap.dedent("""
    import os, sys
    import numba
    if sys.argv[1] == "own-kernel-first":
        numba.njit(lambda x: x + 1)(1)
    from numba.core import config
    from numba.core.registry import cpu_target
    from pipestitch._runtime import kernel_cache
    if sys.argv[1].startswith("then-"):   # a kernel, then the processor's name changed
        numba.njit(lambda x: x + 1)(1)
        os.environ["NUMBA_CPU_NAME"] = sys.argv[1][5:]
        config.reload_config()
    print("|".join(cpu_target.target_context.codegen().magic_tuple()))
""")


def _child_target(monkeypatch: pytest.MonkeyPatch, first: str = "", cwd: Path | None = None,
                  **numba_env: str) -> list[str]:
    for name in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES"):
        monkeypatch.delenv(name, raising=False)
    for name, value in numba_env.items():
        monkeypatch.setenv(name, value)
    proc = subprocess.run([sys.executable, "-c", TARGET, first], capture_output=True,
                          text=True, timeout=300, check=False, cwd=cwd)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.strip().splitlines()[-1].split("|")


def _cpuinfo_flags() -> set[str]:
    """The processor's flags as Linux lists them (empty elsewhere)."""
    path = Path("/proc/cpuinfo")
    if not path.is_file():
        return set()
    for line in path.read_text().splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def test_kernels_are_compiled_for_the_best_level_the_processor_runs(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # What Linux says the processor has, apart from LLVM's view that the code reads:
    # level 3 is AVX2, FMA, BMI1/2, F16C, MOVBE, LZCNT (abm), XSAVE, SSE4.2, POPCNT,
    # CMPXCHG16B; level 4 adds AVX-512 F, BW, CD, DQ and VL
    level_3 = {"avx2", "fma", "bmi1", "bmi2", "f16c", "movbe", "abm", "xsave", "sse4_2",
               "popcnt", "cx16"}
    level_4 = level_3 | {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"}
    flags = _cpuinfo_flags()
    if platform.machine().lower() not in ("x86_64", "amd64") or not level_3 <= flags:
        pytest.skip("not an x86-64-v3 processor under Linux")
    level = "x86-64-v4" if level_4 <= flags else "x86-64-v3"
    _, name, features = _child_target(monkeypatch)
    assert (name, features) == (level, kernel_cache.level_features(level))
    # a name changed after the first kernel (numba reads the name in its key afresh,
    # the features as its compiler was made): no key of the other level's code
    other = "x86-64-v3" if level == "x86-64-v4" else "x86-64-v4"
    _, name, features = _child_target(monkeypatch, f"then-{other}")
    assert (name, features) != (other, kernel_cache.level_features(other))
    assert features == kernel_cache.level_features(level)


def test_the_users_choice_of_processor_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    _, name, features = _child_target(monkeypatch, NUMBA_CPU_NAME="generic")
    assert (name, features) == ("generic", "")


def test_the_processor_in_numbas_configuration_file_is_kept(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / ".numba_config.yaml").write_text("cpu_name: generic\n")
    _, name, features = _child_target(monkeypatch, cwd=tmp_path)
    assert (name, features) == ("generic", "")


def test_avx_turned_off_by_the_user_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    import llvmlite.binding as llvm

    _, name, features = _child_target(monkeypatch, NUMBA_ENABLE_AVX="0")
    assert name == llvm.get_host_cpu_name()
    assert "+avx" not in features


def test_a_process_that_compiled_for_its_own_processor_keeps_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # numba makes its compiler once, at the first kernel: the package's kernels are
    # then compiled (and cached) for that processor, never labelled as another's
    import llvmlite.binding as llvm

    _, name, _ = _child_target(monkeypatch, "own-kernel-first")
    assert name == llvm.get_host_cpu_name()


def test_the_levels_are_the_psabis() -> None:
    # x86-64 psABI: v1 CMOV CX8 FPU FXSR MMX OSFXSR SCE SSE SSE2; v2 CMPXCHG16B LAHF-SAHF
    # POPCNT SSE3 SSE4_1 SSE4_2 SSSE3; v3 AVX AVX2 BMI1 BMI2 F16C FMA LZCNT MOVBE OSXSAVE;
    # v4 AVX512F AVX512BW AVX512CD AVX512DQ AVX512VL (LLVM's names; the x87 unit, SCE
    # and OSFXSR every x86-64 processor has)
    v3 = {"cmov", "cx8", "fxsr", "mmx", "sse", "sse2", "cx16", "sahf", "popcnt", "sse3",
          "sse4.1", "sse4.2", "ssse3", "avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt",
          "movbe", "xsave"}
    assert set(kernel_cache.LEVEL_3) == v3
    assert set(kernel_cache.LEVEL_4) == v3 | {"avx512f", "avx512bw", "avx512cd", "avx512dq",
                                              "avx512vl"}


def test_the_level_is_the_best_whose_every_feature_the_processor_has() -> None:
    level_3 = dict.fromkeys(kernel_cache.LEVEL_3, True)
    level_4 = dict.fromkeys(kernel_cache.LEVEL_4, True)
    assert kernel_cache.portable_cpu("x86_64", level_3) == "x86-64-v3"
    assert kernel_cache.portable_cpu("AMD64", level_4 | {"avx512fp16": True}) == "x86-64-v4"
    for name in ("avx512vl", "avx512dq"):
        assert kernel_cache.portable_cpu("x86_64", level_4 | {name: False}) == "x86-64-v3"
    for name in ("avx2", "fma", "movbe", "sse4.2"):
        assert kernel_cache.portable_cpu("x86_64", level_4 | {name: False}) is None
        assert kernel_cache.portable_cpu("x86_64", {k: v for k, v in level_3.items()
                                                    if k != name}) is None
    assert kernel_cache.portable_cpu("aarch64", level_4) is None


# A child interpreter that saves ``n`` entries of one function's cache in ``folder`` as
# this package's kernels are saved (their stamp), each naming its own code.
SAVER = textwrap.dedent("""
    import os, sys, time
    from numba.core import caching
    from pipestitch._runtime import kernel_cache, kernel_sources  # noqa: F401
    folder, worker, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    cache = caching.IndexDataCacheFile(folder, "f-1.py311", kernel_sources.sources_stamp())
    open(os.path.join(folder, f"ready-{worker}"), "w").close()
    while not os.path.exists(os.path.join(folder, "go")):   # all start saving at once
        time.sleep(0.001)
    for i in range(n):
        cache.save((f"signature {worker}.{i}", ("x86_64", "level", ""), ("code", "")),
                   f"code of {worker}.{i}")
""")


def test_kernels_saved_by_several_processes_at_once_keep_their_own_code(
        tmp_path: Path) -> None:
    # numba's own save numbers the data files as it reads the index: processes saving at
    # once take the same numbers, lose each other's entries and can name one entry's
    # file with another's code (a set-up's pool did so)
    children = [subprocess.Popen([sys.executable, "-c", SAVER, str(tmp_path), str(w), "150"])
                for w in range(3)]
    deadline = time.monotonic() + 120
    while len(list(tmp_path.glob("ready-*"))) < 3:   # every child imported and waiting
        assert time.monotonic() < deadline, "the savers did not start"
        assert all(child.poll() is None for child in children), "a saver failed to start"
        time.sleep(0.01)
    (tmp_path / "go").touch()
    assert [child.wait(timeout=300) for child in children] == [0, 0, 0]
    cache = caching.IndexDataCacheFile(str(tmp_path), "f-1.py311",
                                       kernel_sources.sources_stamp())
    index = cache._load_index()
    assert len(index) == 3 * 150
    for key in index:
        assert cache.load(key) == f"code of {key[0].split()[-1]}"


def test_a_kernel_is_saved_where_the_folder_cannot_be_locked(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    class NoLocks:
        LOCK_EX = 2

        @staticmethod
        def flock(handle: object, operation: int) -> None:
            raise OSError(37, "No locks available")

    monkeypatch.setattr(kernel_cache, "fcntl", NoLocks)
    cache = caching.IndexDataCacheFile(str(tmp_path), "f-1.py311",
                                       kernel_sources.sources_stamp())
    key = ("signature", ("x86_64", "level", ""), ("code", ""))
    cache.save(key, "its code")
    assert cache.load(key) == "its code"
