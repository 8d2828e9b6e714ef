"""The Python API: docs/api.md's example runs as written, and results are typed."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import pipestitch.api as ps
from pipestitch.errors import DatasetError

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def test_the_documented_example_runs(tmp_path, monkeypatch) -> None:
    block = re.search(r"```python\n(.*?)```", DOC.read_text(), re.S)
    assert block, "docs/api.md has no python example"
    monkeypatch.chdir(tmp_path)
    exec(compile(block.group(1), str(DOC), "exec"), {})
    assert (tmp_path / "api_out" / "report.html").is_file()


def test_read_table_types_columns(tmp_path) -> None:
    path = tmp_path / "t.csv"
    path.write_text("frame,alpha_deg,error\n0,1.5,\n1,nan,no ring\n2,,\n")
    table = ps.read_table(path)
    np.testing.assert_array_equal(table["frame"], [0.0, 1.0, 2.0])
    assert np.isnan(table["alpha_deg"][1:]).all() and table["alpha_deg"][0] == 1.5
    assert list(table["error"]) == ["", "no ring", ""]


def test_read_table_of_a_header_only_file_and_a_missing_file(tmp_path) -> None:
    path = tmp_path / "empty.csv"
    path.write_text("kind,z_mm\n")
    assert {k: v.size for k, v in ps.read_table(path).items()} == {"kind": 0, "z_mm": 0}
    with pytest.raises(DatasetError, match=r"missing\.csv"):
        ps.read_table(tmp_path / "missing.csv")


def test_unknown_scenario_is_refused(tmp_path) -> None:
    with pytest.raises(ValueError, match="scenario"):
        ps.simulate(tmp_path / "x", scenario="no-such-scenario")


def test_simulate_takes_the_led_frames_share(tmp_path) -> None:
    made = ps.simulate(tmp_path / "moving", scenario="default", pairs=2, led_share=0.5)
    assert made.n_pairs == 2 and (tmp_path / "moving" / "truth" / "led_poses.csv").is_file()
    with pytest.raises(ValueError, match="led_share"):
        ps.simulate(tmp_path / "x", scenario="default", pairs=2, led_share=1.5)
