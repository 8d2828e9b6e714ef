"""Every compiled kernel is compiled with one set of float options, whoever calls it first.

A numba kernel that sets no ``fastmath`` takes its caller's when it is compiled as that
caller's callee, and keeps that code for every later caller (numba's flags inheritance):
a kernel called both from a ``fastmath`` kernel and from one without (or from Python)
would then compute differently, in its last bits, with the order in which a process
happened to compile them: the set-up's order against a first run's, which once moved
outputs at ~1e-12. So each kernel must have a single possible ``fastmath``: its own, or
the one every caller passes on. ``error_model`` is inherited the same way (whether a
division by zero raises), so it is held to the same rule. A kernel inlined into its
callers (``inline="always"``) is compiled with each caller's options whatever its own,
and with its own only when Python calls it: it too must come out with one.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import textwrap
from collections.abc import Callable
from types import ModuleType

from numba.core.registry import CPUDispatcher

import pipestitch


def _modules() -> list[ModuleType]:
    """Every pipestitch module (not the command line's ``__main__``, which runs it)."""
    return [importlib.import_module(info.name)
            for info in pkgutil.walk_packages(pipestitch.__path__, "pipestitch.")
            if not info.name.endswith("__main__")]


def _kernels() -> dict[int, CPUDispatcher]:
    """Every numba kernel defined in pipestitch, by id."""
    return {id(value): value for module in _modules() for value in vars(module).values()
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__}


def _called(tree: ast.AST, names: dict) -> set[int]:
    """The kernels the calls in ``tree`` name (plain names and module attributes,
    resolved in ``names``)."""
    out = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        func, target = node.func, None
        if isinstance(func, ast.Name):
            target = names.get(func.id)
        elif isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
            target = getattr(names.get(func.value.id), func.attr, None)
        if isinstance(target, CPUDispatcher):
            out.add(id(target))
    return out


def _called_from_python() -> set[int]:
    """The kernels that pipestitch's Python code (outside the kernels) calls."""
    out = set()
    for module in _modules():
        tree = ast.parse(inspect.getsource(module))
        for node in ast.walk(tree):   # the kernels' own bodies left out
            if isinstance(node, ast.FunctionDef) and isinstance(
                    vars(module).get(node.name), CPUDispatcher):
                node.body = []
        out |= _called(tree, vars(module))
    return out


def _callees(kernel: CPUDispatcher) -> set[int]:
    """The kernels ``kernel``'s source calls."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(kernel.py_func)))
    return _called(tree, kernel.py_func.__globals__)


def _fastmath(kernel: CPUDispatcher) -> frozenset | None:
    """The kernel's own fastmath flags, or None when it sets none (it inherits)."""
    if "fastmath" not in kernel.targetoptions:
        return None
    value = kernel.targetoptions["fastmath"]
    if value is True:
        return frozenset({"fast"})
    return frozenset(value) if value else frozenset()


def _error_model(kernel: CPUDispatcher) -> str | None:
    """The kernel's own error model, or None when it sets none (it inherits)."""
    return kernel.targetoptions.get("error_model")


def _ambiguous(option: Callable[[CPUDispatcher], object], default: object) -> list[str]:
    """The kernels that could be compiled with two values of an inherited ``option``:
    their own, else any their callers can have (``default`` when called from Python, or
    called by no kernel: from a test or a user); an inlined kernel any its callers can
    have, and its own (else ``default``) when called from outside kernels."""
    kernels = _kernels()
    assert len(kernels) > 100   # the walk found the package's kernels
    callers: dict[int, set[int]] = {k: set() for k in kernels}
    for k, d in kernels.items():
        for c in _callees(d) & kernels.keys():
            callers[c].add(k)
    own = {k: option(d) for k, d in kernels.items()}
    inlined = {k for k, d in kernels.items() if d.targetoptions.get("inline") == "always"}
    python = _called_from_python()
    outside = {k for k in kernels if k in python or not callers[k]}
    possible = {k: ({own[k] if own[k] is not None else default} if k in outside else set())
                if own[k] is None or k in inlined else {own[k]} for k in kernels}
    changed = True
    while changed:
        changed = False
        for k in kernels:
            if (own[k] is None or k in inlined) and callers[k]:
                new = set().union(*(possible[c] for c in callers[k]))
                if not new <= possible[k]:
                    possible[k] |= new
                    changed = True
    return sorted(f"{d.py_func.__module__}.{d.py_func.__name__}: {sorted(map(str, possible[k]))}"
                  for k, d in kernels.items() if len(possible[k]) > 1)


def test_each_kernel_has_one_possible_fastmath() -> None:
    ambiguous = _ambiguous(_fastmath, frozenset())
    assert not ambiguous, ambiguous


def test_each_kernel_has_one_possible_error_model() -> None:
    # inherited the same way: "python" raises on a division by zero, "numpy" gives inf
    ambiguous = _ambiguous(_error_model, "python")
    assert not ambiguous, ambiguous
