"""Every compiled kernel is compiled with one set of float options, whoever calls it first.

A numba kernel that sets no ``fastmath`` takes its caller's when it is compiled as that
caller's callee, and keeps that code for every later caller (numba's flags inheritance):
a kernel called both from a ``fastmath`` kernel and from one without (or from Python)
would then compute differently, in its last bits, with the order in which a process
happened to compile them: the set-up's order against a first run's, which once moved
outputs at ~1e-12. So each kernel must have a single possible ``fastmath``: its own, or
the one every caller passes on.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import textwrap

from numba.core.registry import CPUDispatcher

import pipestitch


def _kernels() -> dict[int, CPUDispatcher]:
    """Every numba kernel defined in pipestitch, by id."""
    found = {}
    for info in pkgutil.walk_packages(pipestitch.__path__, "pipestitch."):
        if info.name.endswith("__main__"):   # runs the command line
            continue
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == info.name:
                found[id(value)] = value
    return found


def _callees(kernel: CPUDispatcher) -> set[int]:
    """The kernels ``kernel``'s source calls (names and module attributes resolved)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(kernel.py_func)))
    names = kernel.py_func.__globals__
    out = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        target = None
        if isinstance(func, ast.Name):
            target = names.get(func.id)
        elif isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
            target = getattr(names.get(func.value.id), func.attr, None)
        if isinstance(target, CPUDispatcher):
            out.add(id(target))
    return out


def _own(kernel: CPUDispatcher) -> frozenset | None:
    """The kernel's own fastmath flags, or None when it sets none (it inherits)."""
    if "fastmath" not in kernel.targetoptions:
        return None
    value = kernel.targetoptions["fastmath"]
    if value is True:
        return frozenset({"fast"})
    return frozenset(value) if value else frozenset()


def test_each_kernel_has_one_possible_fastmath() -> None:
    kernels = _kernels()
    assert len(kernels) > 100   # the walk found the package's kernels
    calls = {k: _callees(d) for k, d in kernels.items()}
    callers: dict[int, set[int]] = {k: set() for k in kernels}
    for k, callees in calls.items():
        for c in callees & kernels.keys():
            callers[c].add(k)
    # what each kernel can be compiled with: its own flags, else its callers' (and the
    # default, no flags, when nothing compiled calls it: a call from Python)
    possible = {k: ({_own(d)} if _own(d) is not None
                    else set() if callers[k] else {frozenset()})
                for k, d in kernels.items()}
    changed = True
    while changed:
        changed = False
        for k, d in kernels.items():
            if _own(d) is not None:
                continue
            new = set().union(*(possible[c] for c in callers[k])) if callers[k] else possible[k]
            if not new <= possible[k]:
                possible[k] |= new
                changed = True
    ambiguous = sorted(f"{d.py_func.__module__}.{d.py_func.__name__}: "
                       f"{sorted(sorted(p) for p in possible[k])}"
                       for k, d in kernels.items() if len(possible[k]) > 1)
    assert not ambiguous, ambiguous
