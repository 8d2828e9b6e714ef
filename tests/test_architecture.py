"""Imports point one way: cli -> pipeline -> io / stages -> geometry, camera."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "pipestitch"

# For each layer, the pipestitch packages/modules it must not import.
FORBIDDEN = {
    "camera": {"geometry", "ring", "pose_fit", "ambiguity", "unwrap", "photometric", "simulate",
               "io", "pipeline", "cli", "config"},
    "geometry": {"ring", "pose_fit", "ambiguity", "unwrap", "photometric", "simulate", "io",
                 "pipeline", "cli", "config"},
    "ring": {"io", "pipeline", "cli", "simulate"},
    "pose_fit": {"io", "pipeline", "cli", "simulate"},
    "section_fit": {"io", "pipeline", "cli", "simulate"},
    "ambiguity": {"io", "pipeline", "cli", "simulate"},
    "unwrap": {"io", "pipeline", "cli", "simulate"},
    "photometric": {"io", "pipeline", "cli", "simulate"},
    "simulate": {"io", "pipeline", "cli"},
    "calibrate": {"io", "pipeline", "cli", "simulate", "report"},
    "standards": {"io", "pipeline", "cli", "simulate", "report", "config"},
    "io": {"pipeline", "cli"},
    "pipeline": {"cli"},
    "scratch": {"camera", "geometry", "ring", "unwrap", "simulate", "io", "pipeline", "cli",
                "config"},
}


def imported_parts(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "pipestitch" and len(parts) > 1:
                out.add(parts[1])
    return out


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_point_downwards(layer: str) -> None:
    target = SRC / layer
    files = sorted(target.rglob("*.py")) if target.is_dir() else [SRC / f"{layer}.py"]
    assert files and all(f.is_file() for f in files)
    for f in files:
        bad = imported_parts(f) & FORBIDDEN[layer]
        assert not bad, f"{f.relative_to(SRC)} imports {sorted(bad)}"
