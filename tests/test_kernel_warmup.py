"""The kernels compiled at set-up (``scripts/compile_kernels.py``) are all a run needs."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "compile_kernels.py"

# In a fresh interpreter: compile (or load) every kernel of the list, note each numba
# dispatcher's signatures, run the pipeline in the same process, print what it added.
CHILD = """
import importlib.util, json, sys
import numba.core.registry

spec = importlib.util.spec_from_file_location("compile_kernels", sys.argv[1])
ck = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ck)
ck.compile_entries(list(range(len(ck.KERNELS))))


def signatures():
    out = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("pipestitch"):
            continue
        for obj in list(vars(module).values()):
            if isinstance(obj, numba.core.registry.CPUDispatcher):
                key = f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"
                out[key] = {str(s) for s in obj.signatures}
    return out


before = signatures()
import pipestitch.pose.ring as ring
moved = []   # the ring search's second pass (frames that moved between a pair's two)
kernel = ring.flatten_by_moved_reflectance
def counted(*args):
    moved.append(1)
    return kernel(*args)
ring.flatten_by_moved_reflectance = counted
from pipestitch.cli import main
sys.argv = ["pipestitch", "run", sys.argv[2], "--out", sys.argv[3], "-q"]
try:
    main()
except SystemExit as stop:
    if stop.code:
        raise
after = signatures()
print(json.dumps({"added": {k: sorted(v - before.get(k, set())) for k, v in after.items()
                            if v - before.get(k, set())}, "second_pass": len(moved)}))
"""


def _load_script():
    spec = importlib.util.spec_from_file_location("compile_kernels", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_listed_kernel_exists_and_parses() -> None:
    ck = _load_script()
    for module, name, sig in ck.KERNELS:
        namespace = importlib.import_module(f"pipestitch.{module}")
        kernel = getattr(namespace, name)
        assert hasattr(kernel, "compile"), (module, name)
        types = ck.parse_types(sig, namespace)
        assert len(types) == kernel.py_func.__code__.co_argcount, (module, name)


def test_every_entry_starts_once_and_after_what_it_waits_for() -> None:
    # Two processes, each finishing its entries in the order they started: every entry
    # starts once, and one that waits for others (the fit) only after they finished.
    ck = _load_script()
    index = {entry[:2]: i for i, entry in enumerate(ck.KERNELS)}
    waits = {index[k]: {index[w] for w in v} for k, v in ck.WAITS_FOR.items()}
    assert waits, "the fit waits for its halves"
    assert all(max(w) < k for k, w in waits.items()), "what an entry waits for comes first"
    pending, done, running, started = list(range(len(ck.KERNELS))), set(), [], []
    while pending or running:
        while len(running) < 2 and (i := ck.next_entry(pending, done)) is not None:
            assert waits.get(i, set()) <= done
            pending.remove(i)
            running.append(i)
            started.append(i)
        done.add(running.pop(0))
    assert sorted(started) == list(range(len(ck.KERNELS)))
    fit = index[("pose._fit_kernels", "fit_fields")]
    assert ck.next_entry([fit], set()) is None
    assert ck.next_entry([fit], waits[fit]) == fit


@pytest.mark.slow   # a simulated run and the pipeline in a child process
def test_a_run_compiles_nothing_beyond_the_set_up(tmp_path: Path) -> None:
    # LED frames taken half a step after their laser frames, as a probe that moves
    # between them takes them: the ring search's second pass runs too
    data, out = tmp_path / "data", tmp_path / "out"
    subprocess.run([sys.executable, "-m", "pipestitch.cli", "simulate", "--scenario",
                    "default", "--size", "half", "--pairs", "3", "--led-share", "0.5",
                    "--out", str(data), "-q"],
                   check=True, capture_output=True, timeout=600)
    proc = subprocess.run([sys.executable, "-c", CHILD, str(SCRIPT), str(data), str(out)],
                          capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.strip().splitlines()[-1])
    assert found["second_pass"] > 0, "no frame took the ring search's second pass"
    added = found["added"]
    assert added == {}, f"compiled at run time, not by scripts/compile_kernels.py: {added}"


def test_the_set_up_key_follows_the_kernel_sources(monkeypatch: pytest.MonkeyPatch) -> None:
    # The set-up compiles again (from an empty cache) when the key changes: whenever the
    # stamp numba's cache of the kernels carries changes (tests/_runtime/
    # test_kernel_cache.py: every file kernel code comes from), the cache folder, and
    # the processor the kernels are compiled for.
    from pipestitch._runtime import kernel_cache, kernel_sources

    ck = _load_script()
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    key = ck.source_key()
    assert ck.source_key() == key
    monkeypatch.setattr(kernel_sources, "sources_stamp", lambda: "another stamp")
    assert ck.source_key() != key
    moved = ck.source_key()
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/elsewhere")
    assert ck.source_key() != moved
    elsewhere = ck.source_key()
    monkeypatch.setattr(kernel_cache, "compile_target",
                        lambda: ("x86_64-unknown-linux-gnu", "znver4", "+avx512f"))
    assert ck.source_key() != elsewhere


def test_a_compile_starts_from_an_empty_cache(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    # The set-up removes every cached kernel of the package first (the files of a
    # kernel renamed or removed, and of old stamps), where numba keeps them: beside the
    # sources, or under NUMBA_CACHE_DIR when that is set (then the folders beside the
    # sources are not numba's and are left alone).
    from numba.core.caching import _CacheLocator

    ck = _load_script()
    src = tmp_path / "src" / "pipestitch"
    beside = src / "camera" / "__pycache__"
    beside.mkdir(parents=True)
    (src / "camera" / "ocam.py").write_text("")
    (src / "__init__.py").write_text("")
    user = tmp_path / "user-cache"
    under = user / _CacheLocator.get_suitable_cache_subpath(str(src / "camera" / "ocam.py"))
    files = {"beside": [beside / "ocam._horner-244.py311.nbi",
                        beside / "ocam._horner-244.py311.1.nbc"],
             "under": [under / "ocam.ray_loop-254.py311.nbi"],
             "kept": [beside / "ocam.cpython-311.pyc", under / "other.f-1.py311.nbi",
                      user / "theirs_0123" / "ocam.f-1.py311.nbi"]}

    def make() -> None:
        for f in [f for group in files.values() for f in group]:
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_bytes(b"x")

    monkeypatch.setattr(ck, "SRC", src)
    make()
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert ck.clear_cache() == 2
    assert not any(f.exists() for f in files["beside"])
    assert all(f.exists() for f in files["under"] + files["kept"])
    make()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(user))
    assert ck.clear_cache() == 1
    assert not any(f.exists() for f in files["under"])
    assert all(f.exists() for f in files["beside"] + files["kept"])
