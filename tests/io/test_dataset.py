"""probe.toml, OCamCalib files, images and dataset validation, including bad input."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipestitch.camera import OpenCVFisheyeModel, default_camera
from pipestitch.errors import ConfigError, DatasetError
from pipestitch.io.dataset import check_dataset, open_dataset, read_csv_columns
from pipestitch.io.frame_files import frame_files
from pipestitch.io.images import read_image, write_image
from pipestitch.io.ocamcalib import format_calib_results, parse_calib_results, read_calib_results
from pipestitch.io.probe_toml import (
    format_probe_toml,
    parse_probe_toml,
    probe_config_for,
    read_probe_toml,
    write_probe_toml,
)

SPEC_EXAMPLE = """
[camera]
model = "ocam"            # comment
width = 2448
height = 2048
pol = [-634.0, 0.0, 0.00079]
invpol = [1041.2, 634.5]
center = [1023.5, 1223.5]
affine = [1.0, 0.0, 0.0]
[laser]
plane_distance_mm = 16.0
[probe]
length_mm = 145.0
diameter_mm = 45.0
[pipe]
inner_diameter_mm = 65.0  # nominal
"""


def test_spec_example_parses() -> None:
    cfg = parse_probe_toml(SPEC_EXAMPLE)
    cam = cfg.camera_model()
    assert (cam.width, cam.height, cam.center_row, cam.center_col) == (2448, 2048, 1023.5, 1223.5)
    assert cfg.laser.plane_distance_mm == 16.0 and cfg.pipe.inner_diameter_mm == 65.0


@pytest.mark.parametrize("camera", [default_camera("half"),
                                    OpenCVFisheyeModel(290.0, 289.4, 399.9, 273.9,
                                                       (-0.03, -0.02, 0.002, 0.001), 800, 503)])
def test_probe_toml_round_trip(tmp_path: Path, camera) -> None:
    cfg = probe_config_for(camera, plane_distance_mm=16.0, pipe_diameter_mm=65.0)
    write_probe_toml(tmp_path / "probe.toml", cfg)
    back = read_probe_toml(tmp_path / "probe.toml")
    assert back == cfg
    assert back.camera_model() == camera


@pytest.mark.parametrize("edit,message", [
    (lambda t: t.replace("[pipe]", "[pipe]\ncolour = 1"), r"unknown key \[pipe\] colour"),
    (lambda t: t.replace('"ocam"', '"pinhole"'), r"\[camera\] model"),
    (lambda t: t.replace("plane_distance_mm = 16.0", "plane_distance_mm = nan"),
     r"\[laser\] plane_distance_mm"),
    (lambda t: t.replace("pol = [-634.0, 0.0, 0.00079]\n", ""), "needs pol"),
    (lambda t: t.replace("[laser]", "[laser"), "malformed TOML"),
    (lambda t: t.replace("inner_diameter_mm = 65.0", "inner_diameter_mm = -65.0"),
     "inner_diameter_mm"),
    (lambda t: t.replace("pol = [-634.0", "pol = [634.0"), "negative"),
    (lambda t: t.replace("diameter_mm = 45.0", "diameter_mm = 70.0"),
     r"^some/probe.toml: \[probe\] diameter_mm = 70 does not fit in \[pipe\] inner_diameter_mm"),
])
def test_bad_probe_toml_names_the_problem(edit, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        parse_probe_toml(edit(SPEC_EXAMPLE), "some/probe.toml")
    assert str(info.value).startswith("some/probe.toml")


def test_missing_probe_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        read_probe_toml(tmp_path / "probe.toml")


def test_calib_results_round_trip_and_real_file(shared_data: Path) -> None:
    path = shared_data / "ocam_komatsu_fisheye_1600px" / "calib_results_0.txt"
    cam = read_calib_results(path)
    assert cam.pol[0] == pytest.approx(-4.714441e02)
    assert cam.invpol[0] == pytest.approx(772.405470)
    assert (cam.center_row, cam.center_col) == (794.308657, 798.175741)
    assert (cam.c, cam.d, cam.e) == (1.000305, -0.000277, -0.000925)
    assert parse_calib_results(format_calib_results(cam)) == cam


def test_bad_calib_results() -> None:
    with pytest.raises(ConfigError, match="header says 3"):
        parse_calib_results("3 -100 0\n1 5\n1 2\n1 0 0\n10 10\n")
    with pytest.raises(ConfigError, match="expected 5 numeric lines"):
        parse_calib_results("2 -100 0\n1 5\n")
    with pytest.raises(ConfigError, match="non-numeric"):
        parse_calib_results("2 -100 zero\n1 5\n1 2\n1 0 0\n10 10\n")


def test_images_8_16_bit_colour(tmp_path: Path) -> None:
    grey16 = (np.arange(200, dtype=np.uint16).reshape(10, 20) * 300)
    colour8 = np.dstack([np.full((10, 20), v, np.uint8) for v in (10, 200, 60)])
    write_image(tmp_path / "a.png", grey16)
    write_image(tmp_path / "b.png", colour8)
    a, b = read_image(tmp_path / "a.png"), read_image(tmp_path / "b.png")
    assert a.dtype == np.uint16 and np.array_equal(a, grey16)
    assert b.dtype == np.uint8 and b.shape == (10, 20, 3) and np.array_equal(b, colour8)


def test_corrupt_and_missing_images(tmp_path: Path) -> None:
    (tmp_path / "bad.png").write_bytes(b"\x89PNG not really")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(DatasetError, match="cannot decode"):
        read_image(tmp_path / "bad.png")
    with pytest.raises(DatasetError, match="empty"):
        read_image(tmp_path / "empty.png")
    with pytest.raises(DatasetError, match="not found"):
        read_image(tmp_path / "none.png")


def _tiny_dataset(root: Path, n: int = 3, size=(64, 48), led: bool = True) -> None:
    cam = default_camera("half")
    cfg = probe_config_for(cam, plane_distance_mm=16.0, pipe_diameter_mm=65.0)
    text = format_probe_toml(cfg).replace("width = 1224", f"width = {size[0]}")
    text = text.replace("height = 1024", f"height = {size[1]}")
    (root / "frames").mkdir(parents=True)
    (root / "probe.toml").write_text(text)
    for i in range(n):   # frames with a picture (a black one is warned of: check below)
        img = np.random.default_rng(i).integers(0, 256, (size[1], size[0]), dtype=np.uint8)
        cv2.imwrite(str(root / "frames" / f"laser_{i:05d}.png"), img)
        if led:
            cv2.imwrite(str(root / "frames" / f"led_{i:05d}.png"), img)


def test_valid_dataset_has_no_errors(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path)
    assert [p for p in check_dataset(tmp_path) if p.severity == "error"] == []
    ds = open_dataset(tmp_path)
    assert ds.n_pairs == 3 and ds.has_led and ds.read_led(2).shape == (48, 64)


def test_check_lists_every_problem(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=5)
    frames = tmp_path / "frames"
    (frames / "laser_00002.png").unlink()                       # gap in numbering
    (frames / "led_00003.png").write_bytes(b"garbage")          # corrupt
    cv2.imwrite(str(frames / "led_00004.png"), np.zeros((10, 10), np.uint8))  # wrong size
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,0.0\n1,abc\n")
    problems = check_dataset(tmp_path)
    text = "\n".join(str(p) for p in problems)
    assert "missing laser_00002" in text
    assert "led_00003.png: cannot decode" in text
    assert "led_00004.png: image is 10x10, probe.toml says 64x48" in text
    assert "odometry.csv: line 3: z_mm = 'abc' is not a finite number" in text
    assert "pair 00002 has no laser frame" in text


def test_two_files_of_one_frame_are_bad_input(tmp_path: Path) -> None:
    # laser_00001.png and laser_00001.tif: which is the frame, the names do not say
    _tiny_dataset(tmp_path)
    frames = tmp_path / "frames"
    write_image(frames / "laser_00001.tif", read_image(frames / "laser_00001.png"))
    errors = [str(p) for p in check_dataset(tmp_path) if p.severity == "error"]
    assert errors == [f"error: {frames / 'laser_00001.png'}: the same frame as laser_00001.tif: "
                      "keep one of the two files"]
    with pytest.raises(DatasetError, match=r"laser_00001\.png: the same frame as laser_0000"):
        open_dataset(tmp_path)
    (frames / "laser_00001.png").unlink()
    assert open_dataset(tmp_path).n_pairs == 3


def test_pairs_past_99999_are_numbered_with_six_digits(tmp_path: Path) -> None:
    # SPEC pads the pair's number to five digits; a run of 100,000 pairs or more goes on
    # with six (f"{i:05d}"): those are frames, a number padded further is not
    names = ["laser_99999.png", "led_99999.png", "laser_100000.png", "led_100000.tif",
             "laser_1234567.png", "laser_000001.png", "led_0001.png", "laser_x0001.png"]
    for name in names:
        (tmp_path / name).touch()
    found, other = frame_files(tmp_path)
    assert found == {"laser": {99999: tmp_path / "laser_99999.png",
                               100000: tmp_path / "laser_100000.png",
                               1234567: tmp_path / "laser_1234567.png"},
                     "led": {99999: tmp_path / "led_99999.png",
                             100000: tmp_path / "led_100000.tif"}}
    assert sorted(p.name for p in other) == ["laser_000001.png", "laser_x0001.png",
                                             "led_0001.png"]


def test_a_repeated_frame_is_a_warning(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path)
    frames = tmp_path / "frames"
    (frames / "led_00002.png").write_bytes((frames / "led_00001.png").read_bytes())
    problems = [str(p) for p in check_dataset(tmp_path)]
    assert problems == [f"warning: {frames / 'led_00002.png'}: the same file as "
                        "led_00001.png (a repeated frame: a stalled camera or a copy?)"]
    assert open_dataset(tmp_path).n_pairs == 3


def test_laser_only_dataset_is_a_warning(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, led=False)
    problems = check_dataset(tmp_path)
    assert problems and all(p.severity == "warning" for p in problems)
    assert not open_dataset(tmp_path).has_led


def test_open_dataset_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="dataset folder not found"):
        open_dataset(tmp_path / "nope")
    (tmp_path / "probe.toml").write_text(SPEC_EXAMPLE)
    with pytest.raises(DatasetError, match="frames/ folder not found"):
        open_dataset(tmp_path)
    (tmp_path / "frames").mkdir()
    with pytest.raises(DatasetError, match="no laser frames"):
        open_dataset(tmp_path)


def test_csv_reader_errors(tmp_path: Path) -> None:
    path = tmp_path / "x.csv"
    path.write_text("frame,z\n")
    with pytest.raises(DatasetError, match="missing column"):
        read_csv_columns(path, ("frame", "z_mm"))
    path.write_text("frame,z_mm\n0,nan\n")
    with pytest.raises(DatasetError, match="not a finite number"):
        read_csv_columns(path, ("frame", "z_mm"))


def test_zero_focal_length_is_a_config_error() -> None:
    text = SPEC_EXAMPLE.replace('model = "ocam"', 'model = "opencv_fisheye"').replace(
        "pol = [-634.0, 0.0, 0.00079]", "K = [[0.0, 0.0, 600.0], [0.0, 300.0, 500.0], "
        "[0.0, 0.0, 1.0]]\nD = [0.0, 0.0, 0.0, 0.0]")
    with pytest.raises(ConfigError, match="focal lengths"):
        parse_probe_toml(text)


def test_check_odometry_frames_beyond_the_laser_frames(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,0.0\n4,20.0\n")
    problems = [str(p) for p in check_dataset(tmp_path)]
    # `check` words it as `pose` and `run` do: where the pairs were counted
    assert any("odometry.csv: frame numbers must be integers in 0..2: frames/ holds 3 pair(s) "
               "(line 3: frame 4)" in p for p in problems), problems
    with pytest.raises(DatasetError, match=r"0\.\.2: frames/ holds 3 pair\(s\) \(line 3"):
        open_dataset(tmp_path)
    # a negative frame number is wrong whatever the pairs: they are not mentioned
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,0.0\n-1,20.0\n")
    problems = [str(p) for p in check_dataset(tmp_path)]
    assert any("integers in 0..2 (line 3: frame -1)" in p for p in problems), problems


def test_missing_led_frame_is_per_pair(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "frames" / "led_00001.png").unlink()
    ds = open_dataset(tmp_path)
    assert ds.has_led and ds.led_missing() == [1]
    with pytest.raises(DatasetError, match=r"led_00001\.png: LED frame missing"):
        ds.read_led(1)
    assert ds.read_led(2).shape == (48, 64)


def test_a_missing_led_frame_is_named_as_its_laser_frame_is_stored(tmp_path: Path) -> None:
    # a TIFF dataset's missing LED frame is led_00001.tif, not a .png it never had
    _tiny_dataset(tmp_path, n=3)
    frames = tmp_path / "frames"
    for png in sorted(frames.glob("*.png")):
        write_image(png.with_suffix(".tif"), read_image(png))
        png.unlink()
    (frames / "led_00001.tif").unlink()
    ds = open_dataset(tmp_path)
    assert ds.led_missing() == [1]
    with pytest.raises(DatasetError, match=r"led_00001\.tif: LED frame missing"):
        ds.read_led(1)


def test_mosaic_to_uint8_keeps_zero_for_no_data() -> None:
    from pipestitch.io.outputs import mosaic_to_uint8

    img = np.array([[np.nan, 0.0, 0.5], [1.0, 2.0, np.nan]], np.float32)
    out, scale = mosaic_to_uint8(img)
    assert out[0, 0] == 0 and out[1, 2] == 0
    assert out[0, 1] == 1 and out[1, 1] >= 250 and scale > 0   # 99.5th percentile -> 250


@pytest.mark.parametrize(("probe", "message"), [
    ("[probe]\nlength_mm = 145.0\n", "length_mm is given without diameter_mm"),
    ("[probe]\ndiameter_mm = 45.0\n", "diameter_mm is given without length_mm"),
    ("[probe]\nmask = \" \"\n", "mask: expected a file name"),
])
def test_probe_body_comes_whole_or_not_at_all(probe: str, message: str) -> None:
    text = re.sub(r"\[probe\][^\[]*", "", SPEC_EXAMPLE) + probe
    with pytest.raises(ConfigError, match=message):
        parse_probe_toml(text)


def test_probe_section_is_optional_and_means_no_body() -> None:
    cfg = parse_probe_toml(re.sub(r"\[probe\][^\[]*", "", SPEC_EXAMPLE))
    assert cfg.probe.envelope() is None and cfg.probe.mask is None
    assert "[probe]" not in format_probe_toml(cfg)
    body = parse_probe_toml(SPEC_EXAMPLE).probe.envelope()
    assert (body.length_mm, body.diameter_mm) == (145.0, 45.0)


def test_csv_reader_accepts_a_byte_order_mark(tmp_path: Path) -> None:
    path = tmp_path / "x.csv"
    path.write_bytes(b"\xef\xbb\xbfframe,z_mm\r\n0,1.5\r\n")
    cols = read_csv_columns(path, ("frame", "z_mm"))
    assert list(cols["frame"]) == [0.0] and list(cols["z_mm"]) == [1.5]


def test_odometry_frame_listed_twice_is_an_error_naming_the_line(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,0.0\n\n1,5.0\n1,6.0\n2,9.0\n")
    message = "line 5: frame 1 is listed more than once (first on line 4)"
    with pytest.raises(DatasetError, match=re.escape(message)) as info:
        open_dataset(tmp_path)
    assert info.value.path == tmp_path / "odometry.csv"
    errors = [str(p) for p in check_dataset(tmp_path) if p.severity == "error"]
    assert errors == [f"error: {tmp_path / 'odometry.csv'}: {message}"]


NO_READING = ("no reading (no row, or z_mm nan or empty) for 1 frame(s) (1): their z comes "
              "from registration alone")


@pytest.mark.parametrize("rows,warning", [
    ("0,0.0\n2,9.0\n", NO_READING),
    ("0,0.0\n1,nan\n2,9.0\n", NO_READING),   # nan: not measured, as SPEC's outputs write it
    ("0,0.0\n1,\n2,9.0\n", NO_READING),      # an empty cell alike
    ("0,0.0\n1,5.0\n2,3.0\n", "z_mm is not monotonic: it goes back from frame 1 (5 mm) to "
                              "frame 2 (3 mm)"),
])
def test_odometry_gaps_and_reversals_are_warnings(tmp_path: Path, rows: str,
                                                  warning: str) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n" + rows)
    problems = check_dataset(tmp_path)
    assert [(p.path.name, p.message, p.severity) for p in problems] == [
        ("odometry.csv", warning, "warning")]
    # the passes report these with the run's other messages (tests/pipeline/test_run.py)
    assert open_dataset(tmp_path).odometry_notes == [warning]


def test_odometry_without_any_reading_is_an_error(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,nan\n1,\n")
    with pytest.raises(DatasetError, match="no reading: z_mm is nan or empty on every row"):
        open_dataset(tmp_path)


def test_imu_rows_without_a_reading_are_left_out(tmp_path: Path) -> None:
    from pipestitch.io.imu import read_imu

    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "imu.csv").write_text("frame,roll_deg\n0,nan\n1,\n2,4.5\n")
    assert read_imu(tmp_path) == {2: 4.5}


def test_odometry_pulled_back_is_monotonic(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n0,9.0\n1,5.0\n2,5.0\n")
    assert check_dataset(tmp_path) == []
    assert open_dataset(tmp_path).odometry_notes == []


@pytest.mark.parametrize("text,message", [
    ("frame,roll_deg\n0,abc\n", "line 2: roll_deg = 'abc' is not a finite number"),
    ("frame,roll_deg\n0,inf\n", "line 2: roll_deg = 'inf' is not a finite number"),
    ("frame,roll_deg\n0,nan\n1,\n", "no reading: roll_deg is nan or empty on every row"),
    ("frame,roll_deg\n0,1\n1,2\n0,3\n", "line 4: frame 0 is listed more than once"),
    ("frame,roll_deg\n1.5,1\n", "frame numbers must be whole numbers >= 0 (line 2: frame 1.5)"),
    ("frame,roll_deg\n", "no rows"),
    ("frame,roll\n0,1\n", "missing column(s) roll_deg"),
])
def test_check_reads_imu_csv_as_the_run_does(tmp_path: Path, text: str, message: str) -> None:
    from pipestitch.io.imu import read_imu

    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "imu.csv").write_text(text)
    with pytest.raises(DatasetError, match=re.escape(message)):
        read_imu(tmp_path)
    problems = [p for p in check_dataset(tmp_path) if p.severity == "error"]
    assert len(problems) == 1 and problems[0].path == tmp_path / "imu.csv"
    assert message in problems[0].message


def test_imu_csv_with_a_byte_order_mark(tmp_path: Path) -> None:
    from pipestitch.io.imu import read_imu

    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "imu.csv").write_bytes(b"\xef\xbb\xbfframe,roll_deg\n0,1.5\n2,-3\n")
    assert read_imu(tmp_path) == {0: 1.5, 2: -3.0}
    assert check_dataset(tmp_path) == []


@pytest.mark.parametrize(("text", "got"), [
    ("5", "a number"), ("[1]", "an array"), ('"mm_per_px_axial"', "a string"),
    ("null", "null"), ("true", "true"),
])
def test_truth_wall_json_not_an_object_is_a_problem_naming_it(tmp_path: Path, text: str,
                                                              got: str) -> None:
    _tiny_dataset(tmp_path)
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "wall.json").write_text(text)
    problems = [p for p in check_dataset(tmp_path) if p.severity == "error"]
    assert len(problems) == 1 and problems[0].path == tmp_path / "truth" / "wall.json"
    assert problems[0].message == ("expected a JSON object (mm_per_px_axial, deg_per_px, "
                                   f"z0_mm, radius_mm), got {got}")


def test_a_missing_led_frame_is_a_warning_as_run_takes_it(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=4)
    (tmp_path / "frames" / "led_00002.png").unlink()
    problems = check_dataset(tmp_path)
    assert [(p.severity, "pair 00002 has no led frame" in p.message) for p in problems] == [
        ("warning", True)]
    assert open_dataset(tmp_path).led_missing() == [2]


def test_check_warns_of_a_frame_that_shows_nothing(tmp_path: Path) -> None:
    _tiny_dataset(tmp_path, n=3)
    led = tmp_path / "frames" / "led_00001.png"
    cv2.imwrite(str(led), np.zeros_like(cv2.imread(str(led), cv2.IMREAD_UNCHANGED)))
    problems = check_dataset(tmp_path)
    assert [(p.path.name, p.severity) for p in problems] == [("led_00001.png", "warning")]
    assert "black" in problems[0].message and "not in the mosaic" in problems[0].message


@pytest.mark.parametrize("rows,read", [
    ("0,0.0\n1,-nan\n2,9.0\n", {0: 0.0, 2: 9.0}),
    ("0,0.0\n1,  \n2,9.0\n", {0: 0.0, 2: 9.0}),        # a cell of blanks is empty
    ("0,0.0\n1, nan \n2,9.0\n", {0: 0.0, 2: 9.0}),
])
def test_odometry_cells_that_say_no_reading(tmp_path: Path, rows: str, read: dict) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n" + rows)
    assert open_dataset(tmp_path).odometry_mm == read


@pytest.mark.parametrize("rows,message", [
    ("nan,0.0\n", "line 2: frame = 'nan' is not a finite number"),   # the frame column: no
    ("0,inf\n", "line 2: z_mm = 'inf' is not a finite number"),
    ("0,abc\n", "line 2: z_mm = 'abc' is not a finite number"),
])
def test_odometry_cells_that_are_still_errors(tmp_path: Path, rows: str, message: str) -> None:
    _tiny_dataset(tmp_path, n=3)
    (tmp_path / "odometry.csv").write_text("frame,z_mm\n" + rows)
    with pytest.raises(DatasetError, match=re.escape(message)):
        open_dataset(tmp_path)
