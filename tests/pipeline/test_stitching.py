"""The registration rounds of a run: when another round follows; strips of a camera
whose exposure steps."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.geometry import PipeSection, Pose


def test_another_round_follows_a_large_tilt_correction_or_new_ovals() -> None:
    """One refinement round is linearised about its starting poses: one that moved a
    tilt by more than LINEAR_TILT_DEG, or found frames oval that it had registered as
    circles, is followed by another; small corrections are not."""
    from pipestitch.pipeline.stitching import LINEAR_TILT_DEG, FrameView, _another_round

    section = PipeSection(32.5)
    before = {0: FrameView(Pose(0.01, 0.0, 1.0, 0.0), section),
              1: FrameView(Pose(0.0, 0.02, 0.0, 1.0), section)}
    small = np.deg2rad(0.5 * LINEAR_TILT_DEG)
    after = {0: FrameView(Pose(0.01 + small, 0.0, 1.2, 0.0), section),
             1: FrameView(Pose(0.0, 0.02 - small, 0.0, 1.0), section)}
    assert not _another_round(before, after)
    large = np.deg2rad(1.5 * LINEAR_TILT_DEG)
    assert _another_round(before, {**after, 1: FrameView(Pose(0.0, 0.02 - large, 0, 1),
                                                         section)})
    assert _another_round(before, {**after, 0: FrameView(after[0].pose, section, oval=True)})
    oval_before = {**before, 0: FrameView(before[0].pose, section, oval=True)}
    assert not _another_round(oval_before, {**after, 0: FrameView(after[0].pose, section,
                                                                  oval=True)})


def test_a_camera_whose_exposure_steps_is_stitched_at_one_brightness(tmp_path,
                                                                     simulate_small) -> None:
    """The simulator's auto-exposure camera exposes pairs 8-15 25 % brighter than the
    rest: exactly those strips are scaled back (gain 1/1.25), the others are left alone."""
    from pipestitch.pipeline.run import run_dataset
    from pipestitch.simulate.optics import Optics

    data = simulate_small(tmp_path / "ds", "--scenario", "auto_exposure", "--pairs", "24")
    summary = run_dataset(data, tmp_path / "out", show_progress=False)
    gains = summary.mosaic.gains
    optics = Optics(exposure_step=0.25)
    bright = [i for i in gains if optics.exposure(i) > 1]
    assert bright and len(bright) < len(gains)
    for i, gain in gains.items():
        # each strip's gain is matched to the canvas over hundreds of thousands of
        # nodes: the step is found to a fraction of a percent (0.1-1 % seen)
        want = 1 / optics.exposure(i)
        assert abs(gain / want - 1) < 0.02, (i, gain, want)
    # poses.csv says so, frame by frame
    from pipestitch.io.dataset import read_csv_columns

    written = read_csv_columns(tmp_path / "out" / "poses.csv", ("frame", "exposure_gain"))
    for frame, gain in zip(written["frame"].astype(int), written["exposure_gain"],
                           strict=True):
        assert gain == pytest.approx(gains[frame], abs=5e-5)
