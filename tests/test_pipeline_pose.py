"""The pose stage on simulated runs: oval pipes are flagged, decisions carry reasons."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipestitch.io.dataset import open_dataset, read_csv_columns
from pipestitch.pipeline.pose import estimate_poses, run_pose
from pipestitch.pipeline.simulate import simulate_dataset
from pipestitch.simulate.scenarios import SCENARIOS


def test_oval_pipe_is_not_reported_as_confident_tilt(tmp_path: Path) -> None:
    run = simulate_dataset(SCENARIOS["oval"], tmp_path / "oval", seed=0, size="half",
                           n_pairs=3, show_progress=False)
    frames, _ = estimate_poses(open_dataset(tmp_path / "oval"), show_progress=False)
    # 5 % ovality read as a circle needs ~18° of tilt, which the 145 mm body cannot
    # have in a 65 mm pipe: the frames are refitted as an oval section with the tilt
    # (unobservable from the ring) held at 0, and each frame says so.
    for frame, pose in zip(frames, run.poses, strict=True):
        assert frame.fit.ok and frame.fit.model == "oval/tilt-0"
        assert "cannot see the tilt" in frame.warning
        h = frame.fit.hypotheses[0]
        # Truth: 5 % ovality; the tilt held at 0 adds about tau²/2 (< 0.01 % here).
        assert abs(h.section.ovality - SCENARIOS["oval"].ovality) < 0.002
        assert abs(h.section.mean_radius_mm - run.section.mean_radius_mm) < 0.02
        assert abs(h.section.ovality - run.section.ovality) < 0.002
        assert np.hypot(pose.alpha, pose.beta) < np.deg2rad(1.0)  # what the tilt-0 bound needs
        # The major axis is seen in the probe's roll frame: the world angle minus the roll.
        diff = (h.section.angle - (run.section.angle - pose.roll)) % np.pi
        assert min(diff, np.pi - diff) < np.deg2rad(1.0)


def test_pose_csv_matches_truth_on_a_run(tmp_path: Path) -> None:
    run = simulate_dataset(SCENARIOS["test_piece"], tmp_path / "tp", seed=4, size="half",
                           n_pairs=8, show_progress=False)
    summary = run_pose(tmp_path / "tp", tmp_path / "out", show_progress=False)
    assert summary.n_failed == 0
    cols = read_csv_columns(tmp_path / "out" / "poses.csv",
                            ("alpha_deg", "beta_deg", "dx_mm", "dy_mm", "ambiguous"))
    truth = np.array([[np.rad2deg(p.alpha), np.rad2deg(p.beta), p.dx_mm, p.dy_mm]
                      for p in run.poses])
    est = np.column_stack([cols[k] for k in ("alpha_deg", "beta_deg", "dx_mm", "dy_mm")])
    alt = np.column_stack([cols["alt_" + k] for k in ("alpha_deg", "beta_deg", "dx_mm",
                                                        "dy_mm")])
    decided = cols["ambiguous"] == 0
    # The run's tilt grows to ~2° at its end, where the body envelope rules the mirror
    # out and continuity carries that back over a few frames.
    assert decided.sum() >= 2
    # Decided frames must have chosen the true pose (no silent wrong choice); every
    # frame has the truth among its two hypotheses within the success
    # tolerance T_e = 0.5°/0.5 mm (tilts here are 0.7-2.2°, where a single ring gives
    # the tilt to a few tenths of a degree; see README "Limits, measured").
    ok = np.all(np.abs(est - truth) <= 0.5, axis=1)
    ok_alt = np.all(np.abs(alt - truth) <= 0.5, axis=1)
    assert np.all(ok | ok_alt)
    assert not np.any(decided & ~ok & ok_alt)
