"""A pipe whose radius changes along the run (a concentric reducer): each strip is
unwrapped onto the wall the rings measured there, so the frames' z stay true
(mosaic/wall_profile.py, pipeline/stitching.py). Against the simulator's truth."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import pipestitch.pipeline.stitching as stitching
from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.stitching import MosaicSettings


@pytest.fixture(scope="module")
def reducer(simulate_small, tmp_path_factory):
    return simulate_small(tmp_path_factory.mktemp("reducer") / "ds", "--scenario", "reducer",
                          "--pairs", "12", "--seed", "1")


def _rows(path) -> dict[int, dict[str, str]]:
    with open(path, newline="") as f:
        return {int(r["frame"]): r for r in csv.DictReader(f)}


def _errors(dataset, out) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's z error (the run's median offset removed: z is relative to its start)
    and tilt error (degrees, the larger of alpha's and beta's)."""
    truth, found = _rows(dataset / "truth" / "poses.csv"), _rows(out / "poses.csv")

    def error(column: str) -> np.ndarray:
        return np.array([float(found[i][column]) - float(truth[i][column])
                         for i in sorted(truth)])

    z = error("z_mm")
    return z - np.median(z), np.maximum(np.abs(error("alpha_deg")), np.abs(error("beta_deg")))


def test_a_reducer_leaves_z_and_tilt_true_and_nothing_to_warn(reducer, tmp_path,
                                                              monkeypatch) -> None:
    profile = json.loads((reducer / "truth" / "simulation.json").read_text())
    assert profile["diameter_profile"]["diameter_mm"] == [65.0, 61.0]
    summary = run_dataset(reducer, tmp_path / "out", show_progress=False)
    assert not summary.mosaic_failed
    onto_wall, tilt = _errors(reducer, tmp_path / "out")
    warned = [r for r in _rows(tmp_path / "out" / "poses.csv").values()
              if "strip lies where" in r["warning"]]
    # the strips unwrapped onto their own ring's section alone: z off, frames warned
    with monkeypatch.context() as patch:
        patch.setattr(stitching, "frame_profiles", lambda *a, **k: {})
        run_dataset(reducer, tmp_path / "section", show_progress=False)
    onto_section, section_tilt = _errors(reducer, tmp_path / "section")
    section_warned = [r for r in _rows(tmp_path / "section" / "poses.csv").values()
                      if "strip lies where" in r["warning"]]
    assert np.max(np.abs(onto_wall)) < 0.1, onto_wall
    assert np.max(np.abs(onto_section)) > 5 * np.max(np.abs(onto_wall)), onto_section
    assert not warned and len(section_warned) >= 4
    # the refinement solves the run's tilts together: strips on the wrong wall bent them
    # all; and a ring on the sloping wall misleads its own fit (its prior is loosened)
    assert np.max(tilt) < 0.1 and np.median(tilt) < 0.02, tilt
    assert np.median(section_tilt) > 3 * np.median(tilt), section_tilt
    # the simulator's exposure is constant: the narrow stretch is brighter only because
    # its wall is nearer the LEDs, which the shading says (it took 0.91 as an exposure)
    assert profile["optics"]["exposure_step"] == 0.0
    gains = [float(r["exposure_gain"]) for r in _rows(tmp_path / "out" / "poses.csv").values()]
    assert np.max(np.abs(np.array(gains) - 1.0)) < 0.01, gains


def test_without_the_refinement_the_walls_serve_the_stitch_only(reducer, tmp_path) -> None:
    # refine_iterations 0: the ring's poses as they are, whatever walls are found
    summary = run_dataset(reducer, tmp_path / "out", show_progress=False,
                          settings=MosaicSettings(refine_iterations=0))
    views = summary.mosaic.views
    assert any(v.profile is not None for v in views.values())
    assert not any(v.refined for v in views.values())


def test_pose_widens_the_sigmas_where_the_wall_slopes_and_says_so(reducer, tmp_path) -> None:
    """``pipestitch pose`` on the reducer: the rings on the taper take the wall as
    straight, their offsets 0.14-0.21 mm off against a ring sigma of 0.015-0.025 mm (up
    to 14 sigma). With the odometer's z, the radius change between neighbours widens
    those frames' sigmas (pipeline/sloping_wall.py) and warns; the straight parts keep
    the ring's."""
    from typer.testing import CliRunner

    from pipestitch.cli.app import app

    result = CliRunner().invoke(app, ["pose", str(reducer), "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    truth, found = _rows(reducer / "truth" / "poses.csv"), _rows(tmp_path / "poses.csv")
    radius = {i: float(found[i]["radius_mm"]) for i in found}
    for i in sorted(found):
        row = found[i]
        error = [abs(float(row[c]) - float(truth[i][c])) for c in ("dx_mm", "dy_mm")]
        sigma = [float(row[c]) for c in ("dx_std_mm", "dy_std_mm")]
        assert max(e / s for e, s in zip(error, sigma, strict=True)) < 3, (i, error, sigma)
        neighbours = [radius[k] for k in (i - 1, i + 1) if k in radius]
        on_taper = max(neighbours) - min(neighbours) > 0.1
        assert ("radius changes by" in row["warning"]) == on_taper, (i, row["warning"])


def test_sloping_wall_leaves_frames_without_odometer_z_or_a_significant_change() -> None:
    """``on_sloping_wall`` unit cases: no odometer, one posed frame, neighbours at the
    same z, a change within the rings' noise: nothing widened; a ring between two whose
    radii differ is widened, by at most that difference."""
    from pipestitch.geometry import Pose
    from pipestitch.pipeline.posing import FramePose
    from pipestitch.pipeline.sloping_wall import on_sloping_wall
    from pipestitch.pose.ambiguity import Choice
    from pipestitch.pose.fit import Hypothesis, PoseFit

    def frame(index: int, radius: float) -> FramePose:
        h = Hypothesis(Pose.from_degrees(3.0, 0.0, 1.0, 0.0), radius, 0.0, 0.01, 0.1,
                       std={"alpha": 1e-3, "beta": 1e-3, "dx_mm": 0.01, "dy_mm": 0.01,
                            "radius_mm": 0.001})
        return FramePose(index, PoseFit(True, "", (h, h)))

    frames = [frame(0, 32.5), frame(1, 32.3), frame(2, 32.1)]
    choices = [Choice(0, False, "envelope", 1.0)] * 3

    def dx_sigma(odometry) -> list[float]:
        out = on_sloping_wall(frames, choices, odometry, 16.0)
        return [f.fit.hypotheses[0].stated_std["dx_mm"] for f in out]

    assert dx_sigma(None) == [0.01] * 3
    assert dx_sigma({1: 5.0}) == [0.01] * 3                      # one posed frame with z
    assert dx_sigma({0: 5.0, 1: 5.0, 2: 5.0}) == [0.01] * 3      # no z between them
    widened = dx_sigma({0: 0.0, 1: 5.0, 2: 10.0})                 # 0.04 mm per mm
    assert all(w > 0.01 for w in widened)
    assert dx_sigma({0: 0.0, 1: 1e-3, 2: 2e-3})[1] <= np.hypot(0.01, 0.4) + 1e-12
    frames = [frame(0, 32.5), frame(1, 32.5 + 1e-3), frame(2, 32.5)]   # within the noise
    assert dx_sigma({0: 0.0, 1: 5.0, 2: 10.0}) == [0.01] * 3
