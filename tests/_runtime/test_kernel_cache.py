"""Every cached kernel carries one stamp of all the kernel sources (_runtime/kernel_cache)."""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numba.core.registry

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
