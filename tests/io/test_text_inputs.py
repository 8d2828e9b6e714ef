"""The dataset's text files as other tools write them: a UTF-8 byte-order mark (Notepad,
Excel's "CSV UTF-8") and CRLF line ends read exactly as the plain files; a file that is
not UTF-8 at all is bad input naming the file (exit 2), never a traceback."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.camera import default_camera
from pipestitch.cli.app import app
from pipestitch.errors import DatasetError
from pipestitch.io.dataset import check_dataset, open_dataset
from pipestitch.io.imu import read_imu
from pipestitch.io.probe_toml import format_probe_toml, probe_config_for, read_probe_toml
from pipestitch.io.survey_toml import read_survey_toml

BOM = b"\xef\xbb\xbf"
ODOMETRY = "frame,z_mm\n0,0.0\n1,4.5\n2,9.25\n"
IMU = "frame,roll_deg\n0,1.5\n2,-3.0\n"
SURVEY = '# written by hand\npipe_ref = "P-12"\noperator = "A. Inspector"\n'
TRUTH_POSES = ("frame,alpha_deg,beta_deg,dx_mm,dy_mm,z_mm,roll_deg\n"
               "0,1.0,-2.0,0.5,0.25,0.0,0.0\n")
WALL_JSON = '{"mm_per_px_axial": 0.2, "deg_per_px": 0.5, "z0_mm": 0.0, "radius_mm": 32.5}\n'


def _windows(text: str) -> bytes:
    """``text`` as Notepad saves it: byte-order mark, CRLF line ends."""
    return BOM + text.replace("\n", "\r\n").encode("utf-8")


def _dataset(root: Path, *, windows: bool) -> Path:
    """Two tiny frame pairs and every optional text file, plain or as Notepad saves them."""
    cfg = probe_config_for(default_camera("half"), plane_distance_mm=16.0, pipe_diameter_mm=65.0)
    probe = format_probe_toml(cfg).replace("width = 1224", "width = 64")
    probe = probe.replace("height = 1024", "height = 48")
    (root / "frames").mkdir(parents=True)
    (root / "truth").mkdir()
    for i in range(3):
        for kind in ("laser", "led"):   # frames with a picture (check warns of black ones)
            noise = np.random.default_rng(i).integers(0, 256, (48, 64), dtype=np.uint8)
            cv2.imwrite(str(root / "frames" / f"{kind}_{i:05d}.png"), noise)
    files = {"probe.toml": probe, "odometry.csv": ODOMETRY, "imu.csv": IMU,
             "survey.toml": SURVEY, "truth/poses.csv": TRUTH_POSES, "truth/wall.json": WALL_JSON}
    for name, text in files.items():
        (root / name).write_bytes(_windows(text) if windows else text.encode("utf-8"))
    return root


def test_byte_order_mark_and_crlf_read_as_the_plain_files(tmp_path: Path) -> None:
    plain = _dataset(tmp_path / "plain", windows=False)
    windows = _dataset(tmp_path / "windows", windows=True)
    assert (windows / "probe.toml").read_bytes().startswith(BOM + b"# probe.toml")
    assert b"\r\n" in (windows / "odometry.csv").read_bytes()
    assert read_probe_toml(windows / "probe.toml") == read_probe_toml(plain / "probe.toml")
    a, b = open_dataset(plain), open_dataset(windows)
    assert b.odometry_mm == a.odometry_mm == {0: 0.0, 1: 4.5, 2: 9.25}
    assert b.odometry_notes == a.odometry_notes == []
    assert read_imu(windows) == read_imu(plain) == {0: 1.5, 2: -3.0}
    assert read_survey_toml(windows) == read_survey_toml(plain)
    assert read_survey_toml(windows).pipe_ref == "P-12"
    # every reader of check: probe.toml, the CSVs, survey.toml, truth/ (wall.json included)
    assert check_dataset(windows) == check_dataset(plain) == []


@pytest.mark.parametrize("name,latin1", [
    ("probe.toml", "# Kalibrierung bei 20 °C\n"),               # a comment in latin-1
    ("odometry.csv", "frame,z_mm\n0,0.0\n1,4.5 # Länge\n"),
    ("imu.csv", "frame,roll_deg\n0,1.5\n1,2° \n"),
    ("survey.toml", 'operator = "Jürgen Müller"\n'),
])
def test_a_file_that_is_not_utf8_is_bad_input_naming_it(tmp_path: Path, name: str,
                                                         latin1: str) -> None:
    root = _dataset(tmp_path / "ds", windows=False)
    path = root / name
    text = path.read_text(encoding="utf-8")
    # probe.toml keeps its content (the latin-1 comment is extra): the bytes alone are at fault
    body = latin1 + text if name == "probe.toml" else latin1
    path.write_bytes(body.encode("latin-1"))
    problems = [p for p in check_dataset(root) if p.severity == "error"]
    assert [p.path for p in problems] == [path]
    assert "utf-8" in problems[0].message
    if name in ("probe.toml", "odometry.csv"):   # the two files open_dataset reads
        with pytest.raises(DatasetError) as info:
            open_dataset(root)
        assert info.value.path == path
    result = CliRunner().invoke(app, ["check", str(root), "--quiet"])
    assert result.exit_code == 2, result.output
    assert name in result.output and "Traceback" not in result.output
