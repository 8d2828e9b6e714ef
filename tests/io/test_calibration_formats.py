"""Calibration file formats: OCamCalib, MATLAB fisheyeIntrinsics, OpenCV fisheye <-> probe.toml."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.camera import OcamModel, OpenCVFisheyeModel, default_camera, pixel_grid
from pipestitch.cli.app import app
from pipestitch.errors import ConfigError
from pipestitch.io.matlab import (
    matlab_fields,
    ocam_from_matlab,
    read_matlab_fisheye,
    write_matlab_fisheye,
)
from pipestitch.io.ocamcalib import read_calib_results, write_calib_results
from pipestitch.io.opencv_calib import read_opencv_fisheye, write_opencv_fisheye
from pipestitch.io.probe_toml import read_probe_toml

# A lens with a visible affine part and an off-centre centre, so a swapped row/column
# or a wrong 1-based shift shows.
OCAM = OcamModel(pol=(-250.0, 0.0, 1.1e-3, -4e-7, 2e-10), invpol=(), center_row=237.3,
                 center_col=388.9, c=1.004, d=0.012, e=-0.009, width=748, height=480)
FISHEYE = OpenCVFisheyeModel(fx=290.05, fy=289.39, cx=399.94, cy=273.89,
                             k=(-0.0305, -0.0197, 0.0021, 0.0010), width=800, height=503)


def _rays_agree(a, b, step: int = 7) -> float:
    px = pixel_grid(a.width, a.height)[::step]
    ra, rb = a.unproject(px), b.unproject(px)
    ok = np.isfinite(ra[:, 0]) & np.isfinite(rb[:, 0])
    assert ok.sum() > 1000
    return float(np.max(np.linalg.norm(ra[ok] - rb[ok], axis=1)))


def _matlab_unproject(fields: dict, pixels: np.ndarray) -> np.ndarray:
    """MATLAB's documented fisheye model, written independently of io/matlab.py.

    Image point (u, v) (1-based x = column, y = row): [u - cx; v - cy] = S [x'; y'],
    rho = |(x', y')|, world ray = (x', y', a0 + a2 rho² + a3 rho³ + a4 rho⁴), z forward.
    """
    a0, a2, a3, a4 = fields["MappingCoefficients"]
    s = np.array(fields["StretchMatrix"])
    cx, cy = fields["DistortionCenter"]
    uv1 = pixels + 1.0  # MATLAB pixel centres at 1
    xy = np.linalg.solve(s, (uv1 - [cx, cy]).T).T
    rho = np.hypot(xy[:, 0], xy[:, 1])
    rays = np.column_stack([xy, a0 + a2 * rho**2 + a3 * rho**3 + a4 * rho**4])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def test_matlab_fields_follow_matlab_conventions() -> None:
    fields = matlab_fields(OCAM)
    assert fields["MappingCoefficients"][0] == pytest.approx(250.0 * OCAM.c)  # a0 > 0
    assert fields["ImageSize"] == [480, 748]
    px = pixel_grid(OCAM.width, OCAM.height)[::97]
    ours = OCAM.unproject(px)
    ok = np.isfinite(ours[:, 0])
    assert np.max(np.abs(_matlab_unproject(fields, px[ok]) - ours[ok])) < 1e-12
    # The centre pixel maps to the optical axis in both conventions.
    centre = np.array([[OCAM.center_col, OCAM.center_row]])
    assert np.allclose(_matlab_unproject(fields, centre), [[0, 0, 1]], atol=1e-12)


@pytest.mark.parametrize("suffix", [".json", ".mat"])
def test_matlab_round_trip(tmp_path, suffix) -> None:
    path = write_matlab_fisheye(tmp_path / f"intrinsics{suffix}", OCAM)
    back = read_matlab_fisheye(path)
    assert (back.width, back.height) == (OCAM.width, OCAM.height)
    assert back.center_row == pytest.approx(OCAM.center_row, abs=1e-9)
    assert np.allclose(back.pol, OCAM.pol, rtol=1e-12, atol=1e-18)
    assert _rays_agree(back, OCAM) < 1e-12


def test_matlab_rejects_a1_and_bad_files(tmp_path) -> None:
    with pytest.raises(ValueError, match="a1 = 0"):
        matlab_fields(OcamModel(pol=(-250.0, 0.01, 1e-3), invpol=(), center_row=240,
                                center_col=370, c=1, d=0, e=0, width=748, height=480))
    fields = matlab_fields(OCAM)
    del fields["StretchMatrix"]
    with pytest.raises(ConfigError, match="StretchMatrix"):
        ocam_from_matlab(fields, tmp_path / "x.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match=r"bad.json.*malformed JSON"):
        read_matlab_fisheye(bad)
    short = dict(matlab_fields(OCAM), MappingCoefficients=[250.0, 1e-3])
    with pytest.raises(ConfigError, match="MappingCoefficients: expected 4"):
        ocam_from_matlab(short, "x.json")


def test_ocamcalib_round_trip_keeps_the_model(tmp_path) -> None:
    cam = default_camera("half")
    back = read_calib_results(write_calib_results(tmp_path / "calib_results.txt", cam))
    assert _rays_agree(back, cam) < 1e-9


@pytest.mark.parametrize("name", ["k.yaml", "k.yml", "k.json"])
def test_opencv_round_trip(tmp_path, name) -> None:
    back = read_opencv_fisheye(write_opencv_fisheye(tmp_path / name, FISHEYE))
    assert back == FISHEYE


def test_opencv_reads_ros_camera_info_and_rejects_pinhole(tmp_path, shared_data) -> None:
    cam = read_opencv_fisheye(shared_data / "opencv_fisheye_ros_800x503" / "ost.yaml")
    # SOURCE.md: K and k1..k4 of the ROS fisheye calibration (labelled plumb_bob).
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (290.050152, 289.392837, 399.938345, 273.885669)
    assert cam.k == (-0.030464, -0.019695, 0.002098, 0.00103)
    assert (cam.width, cam.height) == (800, 503)
    pinhole = tmp_path / "pinhole.yaml"
    pinhole.write_text("image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                       "  data: [500, 0, 320, 0, 500, 240, 0, 0, 1]\ndistortion_model: plumb_bob\n"
                       "distortion_coefficients:\n  rows: 1\n  cols: 5\n"
                       "  data: [0.1, 0.01, 0, 0, 0]\n")
    with pytest.raises(ConfigError, match=r"pinhole.yaml.*4 fisheye coefficients"):
        read_opencv_fisheye(pinhole)
    missing = tmp_path / "missing.json"
    missing.write_text(json.dumps({"K": FISHEYE.camera_matrix.tolist(), "width": 800}))
    with pytest.raises(ConfigError, match=r"missing key.*D.*height"):
        read_opencv_fisheye(missing)


def test_cli_import_export_round_trips(tmp_path, shared_data) -> None:
    runner = CliRunner()
    probe = tmp_path / "probe.toml"
    source = shared_data / "ocam_urban_backcam_748x480" / "calib_results.txt"
    result = runner.invoke(app, ["calibrate", "import", str(source), "--out", str(probe)])
    assert result.exit_code == 0, result.output
    published = read_calib_results(source)
    assert _rays_agree(read_probe_toml(probe).camera_model(), published) < 1e-12
    for name, fmt in (("m.json", "matlab"), ("m.mat", None), ("c.txt", None)):
        dest = tmp_path / name
        args = ["calibrate", "export", str(probe), "--out", str(dest)]
        result = runner.invoke(app, args + (["--format", fmt] if fmt else []))
        assert result.exit_code == 0, result.output
        again = tmp_path / f"again_{name}.toml"
        result = runner.invoke(app, ["calibrate", "import", str(dest), "--out", str(again)])
        assert result.exit_code == 0, result.output
        assert _rays_agree(read_probe_toml(again).camera_model(), published) < 1e-9
    # ocam cannot be written as OpenCV fisheye; a bad file is exit 2 naming it.
    result = runner.invoke(app, ["calibrate", "export", str(probe), "--out",
                                 str(tmp_path / "k.yaml")])
    assert result.exit_code == 2 and "opencv needs opencv_fisheye" in result.output
    bad = tmp_path / "bad.yaml"
    bad.write_text("image_width: 800\n")
    result = runner.invoke(app, ["calibrate", "import", str(bad), "--out", str(probe)])
    assert result.exit_code == 2 and "bad.yaml" in result.output
    assert "Traceback" not in result.output


@pytest.mark.parametrize("command", ["camera", "laser", "import", "export"])
def test_calibrate_help_has_an_example(command) -> None:
    result = CliRunner().invoke(app, ["calibrate", command, "--help"])
    assert result.exit_code == 0 and f"Example: pipestitch calibrate {command}" in result.output


BOM = b"\xef\xbb\xbf"


@pytest.mark.parametrize(("name", "write", "read", "model"), [
    ("k.json", write_opencv_fisheye, read_opencv_fisheye, FISHEYE),
    ("k.yaml", write_opencv_fisheye, read_opencv_fisheye, FISHEYE),
    ("intrinsics.json", write_matlab_fisheye, read_matlab_fisheye, OCAM),
    ("calib_results.txt", write_calib_results, read_calib_results, OCAM),
])
def test_calibration_files_saved_with_a_byte_order_mark_read_as_the_plain_ones(
        tmp_path, name, write, read, model) -> None:
    """Notepad and other Windows editors save UTF-8 with a byte-order mark; the file
    reads as it did before it was saved."""
    plain = write(tmp_path / name, model)
    marked = tmp_path / "bom" / name
    marked.parent.mkdir()
    marked.write_bytes(BOM + plain.read_bytes())
    assert read(marked) == read(plain)


def test_a_calibration_file_that_is_not_utf8_is_named(tmp_path) -> None:
    path = write_opencv_fisheye(tmp_path / "k.yaml", FISHEYE)
    path.write_bytes(b"# Kalibrierung bei 20 \xb0C\n" + path.read_bytes())
    with pytest.raises(ConfigError, match=r"k\.yaml.*cannot read as text") as info:
        read_opencv_fisheye(path)
    assert info.value.path == path


@pytest.mark.parametrize("text", ["image_width: [800\n", "K: {rows: 3\n"])
def test_malformed_opencv_yaml_is_a_config_error_naming_the_file(tmp_path, text: str) -> None:
    bad = tmp_path / "cal.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigError, match=r"cal.yaml.*malformed YAML"):
        read_opencv_fisheye(bad)
