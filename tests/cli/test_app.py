"""The real command line on small simulated datasets, including bad input."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
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
    # Up to the mirror, the pose is within the success tolerance (0.5 deg).
    assert min(max(abs(a - b) for a, b in zip(v, true, strict=True)) for v in (est, alt)) < 0.5


def test_pose_on_missing_dataset_exit_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["pose", str(tmp_path / "none"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "dataset folder not found" in result.output


def test_unexpected_failure_exits_1_without_traceback(small_dataset: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import pipestitch.cli.app as cli

    def boom(*args: object, **kwargs: object) -> None:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(cli, "run_pose", boom)
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
    # named in probe.toml, the mask is used as it is: nothing is searched for
    text = (data / "probe.toml").read_text().replace("[pipe]", 'mask = "mask.png"\n\n[pipe]')
    (data / "probe.toml").write_text(text)

    def no_search(*args, **kwargs):
        raise AssertionError("the declared mask was not used")

    monkeypatch.setattr(stitching, "find_occluders", no_search)
    result = CliRunner().invoke(app, ["run", str(data), "--out", str(tmp_path / "out"),
                                      "--quiet"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "mosaic.png").is_file()
    result = CliRunner().invoke(app, ["mask", str(tmp_path / "nothing"), "--out",
                                      str(tmp_path / "m.png")])
    assert result.exit_code == 2 and "not found" in result.output
