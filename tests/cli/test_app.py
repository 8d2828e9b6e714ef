"""The real command line on small simulated datasets, including bad input."""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from pipestitch.cli.app import app

runner = CliRunner()


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory: pytest.TempPathFactory, simulate_small) -> Path:
    return simulate_small(tmp_path_factory.mktemp("cli") / "ds", "--pairs", "2", "--seed", "1")


def test_help_explains_every_command() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("simulate", "check", "pose", "demo"):
        assert command in result.output
        sub = runner.invoke(app, [command, "--help"])
        assert sub.exit_code == 0 and "Example: pipestitch" in sub.output


def test_console_script_runs_check(small_dataset: Path) -> None:
    exe = shutil.which("pipestitch") or str(Path(sys.executable).parent / "pipestitch")
    proc = subprocess.run([exe, "check", str(small_dataset), "--quiet"], capture_output=True,
                          text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "OK" in proc.stdout


def test_check_reports_bad_frames_with_exit_2(small_dataset: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(small_dataset, broken)
    (broken / "frames" / "led_00001.png").write_bytes(b"not a png")
    (broken / "frames" / "laser_00000.png").unlink()
    result = runner.invoke(app, ["check", str(broken), "--quiet"])
    assert result.exit_code == 2
    assert "led_00001.png" in result.output and "cannot decode" in result.output
    assert "missing laser_00000" in result.output
    assert "Traceback" not in result.output


def test_check_bad_probe_toml_exit_2(small_dataset: Path, tmp_path: Path) -> None:
    broken = tmp_path / "toml"
    shutil.copytree(small_dataset, broken)
    toml = broken / "probe.toml"
    toml.write_text(toml.read_text().replace('model = "ocam"', 'model = "pinhole"'))
    result = runner.invoke(app, ["check", str(broken), "--quiet"])
    assert result.exit_code == 2 and "probe.toml" in result.output


def test_check_missing_dataset_exit_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["check", str(tmp_path / "nowhere"), "--quiet"])
    assert result.exit_code == 2 and "dataset folder not found" in result.output


@pytest.mark.parametrize("args,message", [
    (["--scenario", "nope"], "unknown scenario"),
    (["--size", "quarter"], "--size"),
    (["--pairs", "0"], "--pairs"),
    (["--led-share", "1.5"], "--led-share"),
    (["--led-share", "nan"], "--led-share"),
    (["--scenario", "table1", "--led-share", "0.5"], "no LED frames"),
])
def test_simulate_bad_options_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    result = runner.invoke(app, ["simulate", "--out", str(tmp_path / "x"), "--quiet", *args])
    assert result.exit_code == 2 and message in result.output


def test_demo_simulates_and_processes_a_run(tmp_path: Path) -> None:
    result = runner.invoke(app, ["demo", "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "dataset" / "frames" / "led_00011.png").is_file()
    assert "report:" in result.output
    for name in ("poses.csv", "mosaic.png", "mosaic.json", "profile.csv", "report.html"):
        assert (tmp_path / "out" / name).is_file(), name
    # the README's `./run-demo --out DIR` run again: the demo's own dataset is processed
    # again (it was refused as a folder that "already holds frames")
    poses = (tmp_path / "out" / "poses.csv").read_text()
    result = runner.invoke(app, ["demo", "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "made by an earlier demo" in result.output and "report:" in result.output
    assert (tmp_path / "out" / "poses.csv").read_text() == poses
    # another size is another demo: not the one in the folder, which is not overwritten
    result = runner.invoke(app, ["demo", "--out", str(tmp_path), "--size", "full", "--quiet"])
    assert result.exit_code == 2 and "already holds frames" in result.output, result.output


def test_messages_with_brackets_are_printed_verbatim(small_dataset: Path, tmp_path: Path) -> None:
    broken = tmp_path / "brackets"
    shutil.copytree(small_dataset, broken)
    toml = broken / "probe.toml"
    toml.write_text(toml.read_text().replace("[pipe]", "[pipe]\nwall = 3"))
    result = runner.invoke(app, ["check", str(broken), "--quiet"])
    assert result.exit_code == 2 and "unknown key [pipe] wall" in result.output


def test_pose_writes_spec_columns_and_keeps_bad_frames(small_dataset: Path,
                                                       tmp_path: Path) -> None:
    import csv

    data = tmp_path / "posedata"
    shutil.copytree(small_dataset, data)
    (data / "frames" / "laser_00001.png").write_bytes(b"corrupt")
    result = runner.invoke(app, ["pose", str(data), "--out", str(tmp_path / "out"), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "laser_00001.png" in result.output and "1 failed" in result.output
    with (tmp_path / "out" / "poses.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    spec = ["frame", "alpha_deg", "beta_deg", "dx_mm", "dy_mm", "z_mm", "roll_deg", "radius_mm",
            "ovality", "rms_px", "ambiguous", "alt_alpha_deg", "alt_beta_deg", "alt_dx_mm",
            "alt_dy_mm"]
    assert list(rows[0])[:len(spec)] == spec
    assert [r["frame"] for r in rows] == ["0", "1"]
    assert rows[1]["error"] and rows[1]["alpha_deg"] == "nan"
    with (data / "truth" / "poses.csv").open() as handle:
        truth = next(csv.DictReader(handle))
    est = [float(rows[0][k]) for k in ("alpha_deg", "beta_deg")]
    alt = [float(rows[0]["alt_" + k]) for k in ("alpha_deg", "beta_deg")]
    true = [float(truth[k]) for k in ("alpha_deg", "beta_deg")]
    # Up to the mirror, the pose is within the success tolerance (0.5 deg); measured from a
    # noisy frame (0.008 deg off here), not equal to the truth the dataset holds beside it.
    assert 0 < min(max(abs(a - b) for a, b in zip(v, true, strict=True))
                   for v in (est, alt)) < 0.5


def test_pose_on_missing_dataset_exit_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["pose", str(tmp_path / "none"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "dataset folder not found" in result.output


def test_unexpected_failure_exits_1_without_traceback(small_dataset: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import pipestitch.pipeline.posing as posing

    def boom(*args: object, **kwargs: object) -> None:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(posing, "run_pose", boom)
    monkeypatch.delenv("PIPESTITCH_DEBUG", raising=False)
    result = runner.invoke(app, ["pose", str(small_dataset), "--out", "/tmp/x", "--quiet"])
    assert result.exit_code == 1
    assert "processing failed" in result.output and "disk on fire" in result.output
    assert "Traceback" not in result.output


def test_pose_survives_odd_frames_and_quotes_messages(small_dataset: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import csv

    import cv2
    import numpy as np

    import pipestitch.pipeline.posing as pose_stage

    data = tmp_path / "odd"
    shutil.copytree(small_dataset, data)
    # Wrong size: the message "image is 10x10, probe.toml says ..." holds a comma.
    cv2.imwrite(str(data / "frames" / "laser_00001.png"), np.zeros((10, 10), np.uint8))
    (data / "frames" / "led_00000.png").unlink()  # pose from the laser frame alone
    real = pose_stage.fit_frame
    calls = []

    def flaky(index, laser, led, settings):
        calls.append(index)
        return real(index, laser, led, settings)

    monkeypatch.setattr(pose_stage, "fit_frame", flaky)
    result = runner.invoke(app, ["pose", str(data), "--out", str(tmp_path / "o"), "--quiet",
                                 "--workers", "1"])
    assert result.exit_code == 0, result.output
    with (tmp_path / "o" / "poses.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert rows[1]["error"].startswith("laser_00001.png: image is 10x10, probe.toml says")
    assert rows[1]["ambiguous"] == "0" and rows[1]["alpha_deg"] == "nan"
    assert "led_00000.png: LED frame missing" in rows[0]["warning"]
    assert rows[0]["alpha_deg"] != "nan"
    assert calls == [0]


def test_pose_exit_1_when_no_frame_has_a_ring(small_dataset: Path, tmp_path: Path) -> None:
    import cv2
    import numpy as np

    data = tmp_path / "dark"
    shutil.copytree(small_dataset, data)
    for p in (data / "frames").glob("laser_*.png"):
        cv2.imwrite(str(p), np.zeros((1024, 1224), np.uint8))
    result = runner.invoke(app, ["pose", str(data), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code == 1 and "no frame gave a pose" in result.output


@pytest.mark.parametrize("command", ["pose", "run"])
def test_a_dataset_of_unreadable_laser_frames_is_bad_input(small_dataset: Path, tmp_path: Path,
                                                          command: str) -> None:
    data = tmp_path / "junk"
    shutil.copytree(small_dataset, data)
    for p in (data / "frames").glob("laser_*.png"):
        p.write_text("not an image")
    result = runner.invoke(app, [command, str(data), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code == 2, result.output
    assert "laser frames can be read" in result.output and "laser_00000.png" in result.output
    assert "Traceback" not in result.output


def test_pose_takes_roll_from_imu_csv_and_refuses_a_bad_one(small_dataset: Path,
                                                           tmp_path: Path) -> None:
    data = tmp_path / "imu"
    shutil.copytree(small_dataset, data)
    (data / "imu.csv").write_text("frame,roll_deg\n0,12.5\n")   # frame 1 not measured
    result = runner.invoke(app, ["pose", str(data), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader((tmp_path / "o" / "poses.csv").open()))
    assert [r["roll_deg"] for r in rows[:2]] == ["12.500000", "nan"]
    (data / "imu.csv").write_text("frame,roll_deg\n0,twelve\n")
    result = runner.invoke(app, ["pose", str(data), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code == 2 and "imu.csv" in result.output and "twelve" in result.output


def test_simulate_refuses_a_folder_with_frames(small_dataset: Path) -> None:
    result = runner.invoke(app, ["simulate", "--out", str(small_dataset), "--quiet"])
    assert result.exit_code == 2 and "already holds frames" in result.output


def test_mask_writes_the_occluders_found_and_a_run_uses_a_declared_mask(
        small_dataset: Path, tmp_path: Path, monkeypatch) -> None:
    import pipestitch.pipeline.stitching as stitching

    data = tmp_path / "ds"
    shutil.copytree(small_dataset, data)
    result = CliRunner().invoke(app, ["mask", str(data), "--out", str(data / "mask.png")])
    assert result.exit_code == 0, result.output
    mask = cv2.imread(str(data / "mask.png"), cv2.IMREAD_UNCHANGED)
    assert mask.shape == (1024, 1224) and set(np.unique(mask)) <= {0, 255}
    # the lens rim, the mirror mount and the arm: a real share of the image, not all of it
    assert 0.2 < float(np.mean(mask == 0)) < 0.6
    # named in probe.toml, the mask is used as it is: no occluder is searched for (the
    # frames are still sampled for their noise and the sensor's stuck pixels)
    text = (data / "probe.toml").read_text().replace("[pipe]", 'mask = "mask.png"\n\n[pipe]')
    (data / "probe.toml").write_text(text)

    def no_search(*args, **kwargs):
        raise AssertionError("the declared mask was not used")

    monkeypatch.setattr(stitching, "occluder_mask", no_search)
    result = CliRunner().invoke(app, ["run", str(data), "--out", str(tmp_path / "out"),
                                      "--quiet"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "mosaic.png").is_file()
    result = CliRunner().invoke(app, ["mask", str(tmp_path / "nothing"), "--out",
                                      str(tmp_path / "m.png")])
    assert result.exit_code == 2 and "not found" in result.output


# --- usage and output-path errors: exit 2, one line naming the option or the path ---

PROC = Path("/proc/pipestitch-test/nowhere")   # cannot be created, even by root
needs_proc = pytest.mark.skipif(not Path("/proc/self").exists(), reason="no /proc")


def _one_error_line(result, *needles: str) -> None:
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    for needle in needles:
        assert needle in lines[0], result.output
    assert "processing failed" not in result.output and "Traceback" not in result.output


@pytest.fixture()
def places(tmp_path: Path) -> dict[str, Path]:
    (tmp_path / "afile").write_text("not a folder")
    (tmp_path / "folder").mkdir()
    return {"file": tmp_path / "afile", "under_file": tmp_path / "afile" / "x.txt",
            "folder": tmp_path / "folder"}


@pytest.mark.parametrize("command,where,needles", [
    (["simulate", "--size", "half", "--out", "{file}"], "file", ["--out", "afile"]),
    (["simulate", "--size", "half", "--out", "{under_file}"], "under_file",
     ["--out", "afile is a file"]),
    (["pose", "{ds}", "--out", "{file}"], "file", ["--out", "afile"]),
    (["run", "{ds}", "--out", "{under_file}"], "under_file", ["--out", "afile is a file"]),
    (["demo", "--out", "{file}"], "file", ["--out", "afile"]),
    (["batch", "{ds}", "--out", "{file}"], "file", ["--out", "afile"]),
    (["export", "{ds}", "--out", "{folder}"], "folder", ["--out", "folder", "a folder"]),
    (["export", "{ds}", "--out", "{under_file}"], "under_file", ["--out", "afile is a file"]),
    (["mask", "{ds}", "--out", "{folder}"], "folder", ["--out", "a folder"]),
    (["calibrate", "camera", "{img}", "--board", "8x6", "--square-mm", "10", "--out",
      "{folder}"], "folder", ["--out", "a folder"]),
    (["calibrate", "camera", "{img}", "--board", "8x6", "--square-mm", "10", "--plot",
      "{under_file}"], "under_file", ["--plot", "afile is a file"]),
    (["calibrate", "laser", "{img}", "--probe", "{folder}", "--pipe-diameter-mm", "65"],
     "folder", ["--probe", "a folder"]),
    (["calibrate", "import", "{ds}/probe.toml", "--out", "{folder}"], "folder",
     ["--out", "a folder"]),
    (["calibrate", "export", "{ds}/probe.toml", "--out", "{folder}/"], "folder",
     ["--out", "a folder"]),
])
def test_output_path_errors_exit_2_naming_the_path(small_dataset: Path, places, command,
                                                   where: str, needles: list[str]) -> None:
    names = {**{k: str(v) for k, v in places.items()}, "ds": str(small_dataset),
             "img": str(small_dataset / "frames" / "laser_00000.png")}
    args = [a.format(**names) for a in command]
    result = runner.invoke(app, [*args, "--quiet"] if command[0] in (
        "simulate", "pose", "run", "demo", "batch") else args)
    _one_error_line(result, str(places[where]), *needles)
    assert sorted(p.name for p in places["folder"].iterdir()) == []


@needs_proc
@pytest.mark.parametrize("command", [
    ["simulate", "--size", "half", "--quiet", "--out", "{proc}"],
    ["pose", "{ds}", "--quiet", "--out", "{proc}"],
    ["run", "{ds}", "--quiet", "--out", "{proc}"],
    ["demo", "--quiet", "--out", "{proc}"],
    ["batch", "{ds}", "--quiet", "--out", "{proc}"],
    ["export", "{ds}", "--out", "{proc}/x.txt"],
    ["mask", "{ds}", "--out", "{proc}/mask.png"],
    ["calibrate", "export", "{ds}/probe.toml", "--out", "{proc}/x.txt"],
    ["calibrate", "import", "{ds}/probe.toml", "--out", "{proc}/probe.toml"],
])
def test_output_paths_that_cannot_be_created_exit_2(small_dataset: Path, command) -> None:
    args = [a.format(ds=small_dataset, proc=PROC) for a in command]
    _one_error_line(runner.invoke(app, args), str(PROC), "--out", "cannot create")


def test_pose_refuses_an_output_folder_inside_the_dataset(small_dataset: Path) -> None:
    result = runner.invoke(app, ["pose", str(small_dataset), "--out",
                                 str(small_dataset / "frames"), "--quiet"])
    _one_error_line(result, "inside the dataset")
    assert not (small_dataset / "frames" / "poses.csv").exists()


@pytest.mark.parametrize("board,square,needle", [
    ("8y6", "10", "--board"), ("0x0", "10", "--board"), ("8x6", "-1", "--square-mm"),
    ("8x6", "nan", "--square-mm"),
])
def test_calibrate_camera_bad_board_options_exit_2(small_dataset: Path, tmp_path: Path,
                                                   board: str, square: str,
                                                   needle: str) -> None:
    result = runner.invoke(app, ["calibrate", "camera",
                                 str(small_dataset / "frames" / "laser_00000.png"),
                                 "--board", board, "--square-mm", square,
                                 "--out", str(tmp_path / "probe.toml")])
    _one_error_line(result, needle)
    assert not (tmp_path / "probe.toml").exists()


def test_bad_parameter_in_a_command_body_is_one_line_exit_2(
        monkeypatch: pytest.MonkeyPatch, small_dataset: Path, tmp_path: Path) -> None:
    import pipestitch.pipeline.posing as posing

    def bad(*args: object, **kwargs: object) -> None:
        raise typer.BadParameter("--workers: too many")

    monkeypatch.setattr(posing, "run_pose", bad)
    result = runner.invoke(app, ["pose", str(small_dataset), "--out", str(tmp_path / "o")])
    _one_error_line(result, "--workers: too many")


@pytest.mark.parametrize("command,option", [
    (["run", "{ds}", "--out", "{tmp}/o", "--quiet", "--crown-deg", "nan"], "--crown-deg"),
    (["measure", "{tmp}", "--crown-deg", "inf"], "--crown-deg"),
    (["export", "{tmp}", "--crown-deg", "nan"], "--crown-deg"),
    (["demo", "--out", "{tmp}/d", "--size", "quarter", "--quiet"], "--size"),
    (["calibrate", "laser", "{ds}/frames/laser_00000.png", "--probe", "{ds}/probe.toml",
      "--pipe-diameter-mm", "nan"], "--pipe-diameter-mm"),
])
def test_non_finite_and_bad_options_exit_2(small_dataset: Path, tmp_path: Path,
                                           command: list[str], option: str) -> None:
    args = [a.format(ds=small_dataset, tmp=tmp_path) for a in command]
    _one_error_line(runner.invoke(app, args), option)
    assert not (tmp_path / "o").exists() and not (tmp_path / "d").exists()


# --- check validates imu.csv and odometry.csv as run reads them ---

@pytest.mark.parametrize("text,needle", [
    ("frame,roll_deg\n0,abc\n1,2\n", "line 2: roll_deg = 'abc' is not a finite number"),
    ("frame,roll_deg\n0,-inf\n1,2\n", "line 2: roll_deg = '-inf' is not a finite number"),
    ("frame,roll_deg\n0,1\n0,2\n", "line 3: frame 0 is listed more than once"),
])
def test_check_and_run_refuse_the_same_bad_imu_csv(small_dataset: Path, tmp_path: Path,
                                                   text: str, needle: str) -> None:
    data = tmp_path / "imu"
    shutil.copytree(small_dataset, data)
    (data / "imu.csv").write_text(text)
    result = runner.invoke(app, ["check", str(data), "--quiet"])
    assert result.exit_code == 2 and f"imu.csv: {needle}" in result.output, result.output
    result = runner.invoke(app, ["run", str(data), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code == 2 and f"imu.csv: {needle}" in result.output, result.output


def test_check_accepts_a_byte_order_mark(small_dataset: Path, tmp_path: Path) -> None:
    data = tmp_path / "bom"
    shutil.copytree(small_dataset, data)
    (data / "imu.csv").write_bytes(b"\xef\xbb\xbfframe,roll_deg\r\n0,1.5\r\n1,2.5\r\n")
    odometry = (data / "odometry.csv").read_bytes()
    (data / "odometry.csv").write_bytes(b"\xef\xbb\xbf" + odometry)
    result = runner.invoke(app, ["check", str(data), "--quiet"])
    assert result.exit_code == 0 and "OK (0 warning(s))" in result.output, result.output


def test_check_and_run_refuse_a_frame_listed_twice_in_odometry(small_dataset: Path,
                                                                tmp_path: Path) -> None:
    data = tmp_path / "odo"
    shutil.copytree(small_dataset, data)
    (data / "odometry.csv").write_text("frame,z_mm\n0,0.0\n1,5.0\n1,6.0\n")
    for args in (["check", str(data)], ["run", str(data), "--out", str(tmp_path / "o")]):
        result = runner.invoke(app, [*args, "--quiet"])
        assert result.exit_code == 2, result.output
        assert "odometry.csv: line 4: frame 1 is listed more than once" in result.output


def test_check_warns_about_a_missing_odometry_row(small_dataset: Path, tmp_path: Path) -> None:
    data = tmp_path / "gap"
    shutil.copytree(small_dataset, data)
    (data / "odometry.csv").write_text("frame,z_mm\n0,0.0\n")
    result = runner.invoke(app, ["check", str(data), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "warning: " in result.output
    assert "odometry.csv: no reading (no row, or z_mm nan or empty) for 1 frame(s) (1)" in \
        result.output


def test_run_takes_a_nan_odometry_reading_as_none(small_dataset: Path, tmp_path: Path) -> None:
    """``nan`` in z_mm (what SPEC's outputs write for a value not measured, and what an
    encoder export may hold for a missed reading) is a frame without a reading: said,
    and its z comes from registration, as for a frame without a row."""
    data = tmp_path / "nan"
    shutil.copytree(small_dataset, data)
    rows = (data / "odometry.csv").read_text().splitlines()
    rows[2] = rows[2].split(",")[0] + ",nan"
    (data / "odometry.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "o"
    result = runner.invoke(app, ["run", str(data), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "odometry.csv: no reading (no row, or z_mm nan or empty) for 1 frame(s) (1)" in \
        result.output
    z = np.genfromtxt(out / "poses.csv", delimiter=",", names=True)["z_mm"]
    assert np.all(np.isfinite(z)) and np.all(np.diff(z) > 0)


def test_check_with_a_video_reads_imu_and_odometry_as_run_does(small_dataset: Path,
                                                               tmp_path: Path) -> None:
    from pipestitch.io.video import write_video

    frames = [cv2.imread(str(small_dataset / "frames" / f"{kind}_{i:05d}.png"),
                         cv2.IMREAD_UNCHANGED) for i in range(2) for kind in ("laser", "led")]
    video = write_video(tmp_path / "v.avi", frames)
    root = tmp_path / "ds"
    root.mkdir()
    shutil.copy(small_dataset / "probe.toml", root / "probe.toml")
    check = ["check", str(root), "--video", str(video), "--quiet"]
    (root / "odometry.csv").write_text("frame,z_mm\n0,0.0\n")
    result = runner.invoke(app, check)
    assert result.exit_code == 0 and "odometry.csv: no reading (no row" in result.output
    (root / "imu.csv").write_bytes(b"\xef\xbb\xbfframe,roll_deg\n0,nan\n")
    result = runner.invoke(app, check)
    assert result.exit_code == 2, result.output
    assert "imu.csv: no reading: roll_deg is nan or empty on every row" in result.output
    (root / "imu.csv").unlink()
    (root / "odometry.csv").write_text("frame,z_mm\n0,0.0\n0,1.0\n1,2.0\n")
    result = runner.invoke(app, check)
    assert result.exit_code == 2 and "odometry.csv: line 3: frame 0 is listed more than once" \
        in result.output


@pytest.mark.parametrize("exc,code,needle", [
    (PermissionError(13, "Permission denied", "/data/out/poses.csv"), 2,
     "error: /data/out/poses.csv: Permission denied"),
    (OSError(28, "No space left on device", "/data/out/poses.csv"), 1, "processing failed"),
])
def test_os_errors_naming_a_path_are_bad_input(small_dataset: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch, exc: OSError,
                                               code: int, needle: str) -> None:
    import pipestitch.pipeline.posing as posing

    def fail(*args: object, **kwargs: object) -> None:
        raise exc

    monkeypatch.setattr(posing, "run_pose", fail)
    monkeypatch.delenv("PIPESTITCH_DEBUG", raising=False)
    result = runner.invoke(app, ["pose", str(small_dataset), "--out", str(tmp_path / "o")])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == code and len(lines) == 1 and needle in lines[0], result.output


@pytest.mark.parametrize("command", ["pose", "run"])
def test_fewer_than_one_worker_is_refused(small_dataset: Path, tmp_path: Path,
                                          command: str) -> None:
    result = CliRunner().invoke(app, [command, str(small_dataset), "--out", str(tmp_path / "o"),
                                      "--workers", "0"])
    assert result.exit_code == 2 and "--workers" in result.output


def test_calibration_formats_in_the_help_are_the_pipelines() -> None:
    from pipestitch.cli import calibrate_command
    from pipestitch.pipeline import calibrating

    assert calibrate_command.FORMATS == calibrating.FORMATS


def test_the_command_line_loads_no_stage_until_a_command_runs() -> None:
    """`pipestitch --help` and usage errors import typer and the scenario list, not the
    pipeline, scipy or the compiled kernels (each command imports what it runs)."""
    import subprocess
    import sys

    heavy = ("pipestitch.pipeline.run", "pipestitch.pipeline.calibrating", "scipy", "numba",
             "pipestitch.mosaic", "pipestitch.pose", "matplotlib")
    code = ("import sys, pipestitch.cli.app; "
            f"print([m for m in {heavy!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


def test_the_command_gives_blas_one_thread_unless_the_user_chose(monkeypatch) -> None:
    from pipestitch.cli import single_threaded_blas

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")   # recorded: restored after the test
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    monkeypatch.setenv("MKL_NUM_THREADS", "4")
    single_threaded_blas()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    assert os.environ["MKL_NUM_THREADS"] == "4"   # the user's choice kept


def test_blas_threads_are_set_before_numpy_loads() -> None:
    probe = ("import os, sys\n"
             "import pipestitch.cli as cli\n"
             "cli.single_threaded_blas()\n"
             "print('numpy' in sys.modules, os.environ['OPENBLAS_NUM_THREADS'])\n")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         env=env, check=True).stdout.split()
    assert out == ["False", "1"]   # the console script sets them before importing the app


def test_check_names_a_truth_wall_json_that_is_not_an_object(small_dataset: Path,
                                                             tmp_path: Path) -> None:
    data = tmp_path / "wall"
    shutil.copytree(small_dataset, data)
    (data / "truth" / "wall.json").write_text("5\n")
    result = runner.invoke(app, ["check", str(data), "--quiet"])
    assert result.exit_code == 2, result.output
    assert "wall.json: expected a JSON object" in result.output
    assert "Traceback" not in result.output


_CONVERTED_INTERRUPT = """
import signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)   # as in a terminal (CI may ignore it)
import pipestitch.pipeline.check as check

def run_check(*args, **kwargs):
    HOW
    raise AssertionError("not reached")

check.run_check = run_check
sys.argv = ["pipestitch", "check", sys.argv[1]]
from pipestitch.cli import main
main()
"""
_HOW = {   # what the command's body does: a library's error ...
    "made of Ctrl-C": "try:\n        signal.raise_signal(signal.SIGINT)\n"
                      "    except KeyboardInterrupt:\n        pass   # (in Rust: no context)\n"
                      "    raise ValueError('Error building validator: KeyboardInterrupt')",
    "while Ctrl-C unwinds": "try:\n        raise KeyboardInterrupt\n"
                            "    finally:\n        raise OSError('clean-up failed')",
    "alone": "raise ValueError('Error building validator')",
}


@pytest.mark.parametrize("how", list(_HOW))
def test_ctrl_c_turned_into_a_librarys_error_still_exits_130(tmp_path: Path, how: str) -> None:
    """pydantic-core turns a KeyboardInterrupt raised while it builds a model into a
    SchemaError; a clean-up may fail while the interrupt unwinds: after Ctrl-C such an
    error is the interrupt (one line, exit 130); the same error alone is a processing
    failure (exit 1)."""
    code = _CONVERTED_INTERRUPT.replace("HOW", _HOW[how])
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                          text=True, check=False, timeout=120)
    said = proc.stdout + proc.stderr
    assert "Traceback" not in said and "not reached" not in said, proc.stderr[-2000:]
    if how == "alone":
        assert proc.returncode == 1 and "processing failed" in said, said
    else:
        assert proc.returncode == 130, said
        assert "interrupted" in said and "processing failed" not in said, said
