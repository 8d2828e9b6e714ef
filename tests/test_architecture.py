"""Imports point one way: cli -> pipeline -> stages -> geometry, camera -> _runtime.

Every package and loose module of ``src/pipestitch`` has a row in ``ALLOWED``: the
pipestitch packages it may import. A new package without a row fails the test, so the
table cannot fall behind the code.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "pipestitch"

BASE = {"errors", "jsonsafe", "_runtime", "imaging"}   # importable from anywhere
PURE = BASE | {"camera", "geometry"}
ALLOWED = {
    "_runtime": set(),
    "errors": set(),
    "jsonsafe": set(),
    "imaging": {"_runtime"},
    "camera": {"errors", "_runtime", "imaging"},
    "geometry": {"camera", "errors"},
    "config": PURE,
    "pose": PURE,
    "mosaic": PURE | {"pose"},
    "measure": PURE,
    "standards": PURE,
    "calibrate": PURE,
    "simulate": PURE | {"mosaic"},               # mosaic.register's phase correlation, to score
    "report": PURE | {"measure", "standards"},
    "io": PURE | {"config"},
    "pipeline": PURE | {"config", "io", "pose", "mosaic", "measure", "standards", "calibrate",
                        "simulate", "report"},
    "api": PURE | {"config", "pipeline", "io", "measure", "simulate"},
    "cli": PURE | {"config", "pipeline", "api", "calibrate", "simulate"},
}


def imported_parts(path: Path) -> set[str]:
    """The pipestitch packages/modules ``path`` imports (first part after ``pipestitch.``)."""
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
            if node.module == "pipestitch":
                names = [f"pipestitch.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "pipestitch" and len(parts) > 1 and parts[1] != "__version__":
                out.add(parts[1])
    return out


def _units() -> list[str]:
    return sorted(p.stem if p.is_file() else p.name for p in SRC.iterdir()
                  if (p.is_dir() and (p / "__init__.py").is_file())
                  or (p.suffix == ".py" and p.stem != "__init__"))


def test_every_package_has_a_rule() -> None:
    assert set(_units()) == set(ALLOWED)


def test_at_most_six_loose_modules() -> None:
    loose = [p.name for p in SRC.glob("*.py")]
    assert len(loose) <= 6, loose


def test_no_module_name_serves_two_stages() -> None:
    """A module's name is used by one package only (``pose/fit.py`` and
    ``pipeline/posing.py``, not ``pipeline/pose.py``); ``__init__``/``__main__`` aside."""
    seen: dict[str, Path] = {}
    units = set(_units())
    for f in SRC.rglob("*.py"):
        if f.stem in {"__init__", "__main__"}:
            continue
        assert f.stem not in units or f.parent.name == f.stem or f.parent == SRC, \
            f"{f.relative_to(SRC)} is named like the package {f.stem}/"
        other = seen.setdefault(f.stem, f)
        assert other == f, f"{f.relative_to(SRC)} and {other.relative_to(SRC)}"


@pytest.mark.parametrize("unit", _units())
def test_imports_point_downwards(unit: str) -> None:
    target = SRC / unit
    files = sorted(target.rglob("*.py")) if target.is_dir() else [SRC / f"{unit}.py"]
    for f in files:
        bad = imported_parts(f) - ALLOWED[unit] - {unit}
        assert not bad, f"{f.relative_to(SRC)} imports {sorted(bad)}"


def test_every_package_says_what_it_may_import() -> None:
    for unit in _units():
        init = SRC / unit / "__init__.py"
        if init.is_file():
            doc = ast.get_docstring(ast.parse(init.read_text())) or ""
            assert "import" in doc, f"{unit}/__init__.py does not say what it may import"
