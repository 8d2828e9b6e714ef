"""The registration rounds of a run: which frames are refined again; strips of a camera
whose exposure steps; frames placed at known positions; a frame's clipping level."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pipestitch.pipeline.stitching as stitching
from pipestitch.camera import default_camera
from pipestitch.geometry import PipeSection, Pose, WallGrid
from pipestitch.io.dataset import TRUTH_POSE_COLUMNS, open_dataset, read_csv_columns
from pipestitch.io.images import read_image
from pipestitch.mosaic.register import Link, Positions, odometer_noise_mm, solve_positions
from pipestitch.pipeline.stitching import (
    FrameView,
    MosaicResult,
    MosaicSettings,
    _mirror_spread,
    _solved,
    _Unwrapper,
    build_mosaic,
)
from pipestitch.simulate.evaluate import WallImage, score_mosaic


def test_frames_are_redone_after_a_large_tilt_correction_or_new_ovals() -> None:
    """One refinement round is linearised about its starting poses: after one that
    moved a tilt by more than LINEAR_TILT_DEG, or found frames oval that it had
    registered as circles, the frames it moved by more than REDO_TILT_DEG and the new
    ovals are refined again; after small corrections, none."""
    from pipestitch.pipeline.stitching import LINEAR_TILT_DEG, REDO_TILT_DEG, _frames_to_redo

    section = PipeSection(32.5)
    before = {k: FrameView(Pose(0.01, 0.02, 1.0, 0.0), section) for k in range(4)}

    def moved(by_deg: dict[int, float], oval: tuple[int, ...] = ()) -> dict[int, FrameView]:
        return {k: FrameView(Pose(0.01 + np.deg2rad(by_deg.get(k, 0.0)), 0.02, 1.1, 0.0),
                             section, oval=k in oval) for k in before}

    small = {0: 0.9 * LINEAR_TILT_DEG, 1: 2 * REDO_TILT_DEG, 2: 0.5 * REDO_TILT_DEG}
    assert _frames_to_redo(before, moved(small)) == []
    assert _frames_to_redo(before, moved({**small, 3: 1.5 * LINEAR_TILT_DEG})) == [0, 1, 3]
    assert _frames_to_redo(before, moved(small, oval=(2,))) == [0, 1, 2]
    oval_before = {**before, 2: FrameView(before[2].pose, section, oval=True)}
    assert _frames_to_redo(oval_before, moved(small, oval=(2,))) == []


def test_runs_of_frames_to_register_again() -> None:
    """Each frame with its span of registered frames on each side, overlapping runs
    merged, gaps in the registered frames respected, unregistered frames ignored."""
    from pipestitch.pipeline.stitching import _segments

    done = [0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14]
    assert _segments(done, [], 2) == []
    assert _segments(done, [4], 2) == []                       # not registered
    assert _segments(done, [0], 2) == [[0, 1, 2]]
    assert _segments(done, [2], 2) == [[0, 1, 2, 3, 5]]          # 4 was not registered
    assert _segments(done, [6, 8], 1) == [[5, 6, 7, 8, 9]]
    assert _segments(done, [6, 12], 1) == [[5, 6, 7], [11, 12, 13]]
    assert _segments(done, [14], 2) == [[12, 13, 14]]


@pytest.fixture(scope="module")
def eight_pairs(tmp_path_factory, simulate_small) -> Path:
    """A corroded half-size run of 8 pairs."""
    return simulate_small(tmp_path_factory.mktemp("eight") / "ds", "--scenario", "corrosion",
                          "--pairs", "8")


def _frame_4_off(root: Path) -> tuple[dict[int, FrameView], dict[int, FrameView]]:
    """The true views, and the same with the ring's information (tilt to 0.1 degrees,
    offsets to 0.05 mm) except frame 4's tilt (near zero tilt the ring measures it
    poorly), which starts 2 degrees off."""
    views, _ = _true_views(root)
    sure = np.diag(1 / np.array([np.deg2rad(0.1), np.deg2rad(0.1), 0.05, 0.05]) ** 2)
    start = {i: replace(v, information=sure) for i, v in views.items()}
    start[4] = replace(start[4], pose=replace(views[4].pose,
                                              alpha=views[4].pose.alpha - np.deg2rad(2.0)),
                       information=np.diag([0.0, 0.0, 1.0, 1.0]) * sure)
    return views, start


def _tilt_deg(a: Pose, b: Pose) -> float:
    return float(np.rad2deg(max(abs(a.alpha - b.alpha), abs(a.beta - b.beta))))


def test_only_the_frames_redone_are_refined_again(eight_pairs: Path, monkeypatch) -> None:
    """A frame started 2 degrees off in tilt is corrected by the first round only to
    the linearisation's accuracy (a few hundredths of a degree per degree); refined
    again on strips unwrapped anew, it comes out as near the simulator's truth as a
    round gets a tilt already near its value (0.01-0.02 degrees seen), and the frames
    that round left alone keep exactly the poses the first round gave them."""
    import pipestitch.pipeline.stitching as stitching

    views, start = _frame_4_off(eight_pairs)
    redone = build_mosaic(open_dataset(eight_pairs), start, MosaicSettings(),
                          show_progress=False)
    monkeypatch.setattr(stitching, "LINEAR_TILT_DEG", np.inf)
    once = build_mosaic(open_dataset(eight_pairs), start, MosaicSettings(),
                        show_progress=False)
    monkeypatch.undo()
    redo = stitching._frames_to_redo(start, once.views)
    assert 4 in redo and len(redo) < len(views)
    for i, view in redone.views.items():
        if i in redo:
            assert view.pose != once.views[i].pose
        else:
            assert view.pose == once.views[i].pose
    assert 0.04 < _tilt_deg(once.views[4].pose, views[4].pose) < 0.2     # 0.063 seen
    assert _tilt_deg(redone.views[4].pose, views[4].pose) < 0.03         # 0.021 seen
    # the same links, once each; those of the redone frames measured again
    pairs = [(ln.i, ln.j) for ln in redone.links]
    assert len(set(pairs)) == len(pairs) == len(once.links)
    assert set(pairs) == {(ln.i, ln.j) for ln in once.links}
    assert any(a != b for a, b in zip(redone.links, once.links, strict=True)
               if 4 in (a.i, a.j))


def _mosaic_with_alternative(root: Path, monkeypatch, off_deg: tuple[float, float]
                             ) -> tuple[MosaicResult, list[list[int]], Pose]:
    """Frame 4 as in :func:`_frame_4_off`, with a second hypothesis ``off_deg`` (alpha,
    beta) from its starting pose: the mosaic, the frames of each registration pass and
    frame 4's true pose."""
    import pipestitch.pipeline.stitching as stitching

    passes: list[list[int]] = []
    register = stitching._register

    def counted(dataset, views, *args, **kwargs):
        passes.append(sorted(views))
        return register(dataset, views, *args, **kwargs)

    monkeypatch.setattr(stitching, "_register", counted)
    views, start = _frame_4_off(root)
    pose = start[4].pose
    other = replace(pose, alpha=pose.alpha + np.deg2rad(off_deg[0]),
                    beta=pose.beta + np.deg2rad(off_deg[1]))
    start[4] = replace(start[4], alternative=FrameView(other, views[4].section))
    result = build_mosaic(open_dataset(root), start, MosaicSettings(), show_progress=False)
    return result, passes, views[4].pose


def test_a_redone_frame_whose_mirror_registration_decided_keeps_its_choice(
        eight_pairs: Path, monkeypatch) -> None:
    """Frame 4 as above, with a second hypothesis 5 degrees off the other way (3 from the
    truth): the first round chooses the nearer one, so the redo measures frame 4's
    links again by their patch shifts alone, without registering it and its neighbours
    with both hypotheses again, and its pose is refined as near the truth as without
    the choice."""
    result, passes, truth = _mosaic_with_alternative(eight_pairs, monkeypatch, (5.0, 0.0))
    assert passes == [list(range(8))]
    assert result.switched.get(4) is False
    assert _tilt_deg(result.views[4].pose, truth) < 0.03


def test_a_redone_frame_whose_mirror_is_undecided_is_registered_again(
        eight_pairs: Path, monkeypatch) -> None:
    """Frame 4 as above, with a second hypothesis 0.02 degrees from the first, which no
    registration can tell apart: the frames around it (2 registered frames on each
    side) are registered again as in a full round, and its pose is refined as near the
    truth as without a second hypothesis."""
    result, passes, truth = _mosaic_with_alternative(eight_pairs, monkeypatch, (0.0, 0.02))
    assert passes == [list(range(8)), [2, 3, 4, 5, 6]]
    assert _tilt_deg(result.views[4].pose, truth) < 0.03


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



def _true_views(root: Path) -> tuple[dict[int, FrameView], Positions]:
    """Every frame's true view (pose without roll, true circular section) and the true
    positions of a simulated dataset."""
    truth = read_csv_columns(root / "truth" / "poses.csv", TRUTH_POSE_COLUMNS)
    radius = json.loads((root / "truth" / "wall.json").read_text())["radius_mm"]
    views = {int(f): FrameView(Pose.from_degrees(*(float(truth[c][k])
                                                   for c in TRUTH_POSE_COLUMNS[1:5])),
                               PipeSection(radius))
             for k, f in enumerate(truth["frame"])}
    return views, Positions(truth["z_mm"].copy(), truth["roll_deg"].copy(), 1.0, [])


def test_frames_are_placed_at_given_positions(tmp_path: Path, simulate_small) -> None:
    """With known positions (here the simulator's truth) the frames are placed there,
    not where registration would put them (z from the odometer's median, roll 0 at the
    first frame): the result carries the given positions, a frame whose position is
    NaN is skipped, and the mosaic lies in the truth's coordinates."""
    root = simulate_small(tmp_path / "ds", "--scenario", "corrosion", "--pairs", "4")
    views, positions = _true_views(root)
    positions.z_mm[2] = np.nan
    settings = MosaicSettings(refine_iterations=0)
    result = build_mosaic(open_dataset(root), views, settings, show_progress=False,
                          positions=positions)
    assert result.positions is positions
    assert result.placed == [0, 1, 3]
    assert set(result.skipped) == {2} and "no position" in result.skipped[2]
    meta = json.loads((root / "truth" / "wall.json").read_text())
    wall = read_image(root / "truth" / "wall.png").astype(np.float32) / 255
    truth = WallImage(image=wall, grid=WallGrid.from_json(meta, wall.shape[1]))
    s = score_mosaic(WallImage(image=result.image, grid=result.grid), truth, 0.0, 0.0)
    # Placed in true coordinates, the score's alignment (median patch displacement)
    # moves the mosaic by a fraction of a pixel (~0.001 mm and 0.001 deg seen); the
    # true roll of frame 0 alone is degrees away from the 0 registration would give.
    assert abs(s.z_offset_mm) < 0.25 * result.grid.mm_per_px_axial
    assert abs(s.roll_offset_deg) < 0.25 * result.grid.deg_per_px
    assert abs(positions.roll_deg[0]) > 5 * result.grid.deg_per_px
    # True poses and positions on a corroded wall: 0.99 seen
    assert 0.95 < s.ssim <= 1.0
    short = Positions(positions.z_mm[:-1], positions.roll_deg[:-1], 1.0, [])
    with pytest.raises(ValueError, match="positions"):
        build_mosaic(open_dataset(root), views, settings, show_progress=False,
                     positions=short)


def test_a_frame_s_clipping_level_is_found_once_per_run_and_per_frame() -> None:
    """The flat-field round and the stitch read the level each frame had on its first
    unwrap that needed it; another frame gets its own."""
    unwrapper = _Unwrapper(default_camera("half"), MosaicSettings(), 32.5,
                           np.zeros((1, 1), bool), (0.0, 0.0), np.zeros(2))
    clipped = np.full((100, 100), 0.5, np.float32)
    clipped[:5, :5] = 1.0                      # 25 of 10 000 pixels at the maximum: a plateau
    unclipped = np.full((100, 100), 0.5, np.float32)
    unclipped[0, 0] = 1.0                      # the maximum held by one pixel: light
    assert unwrapper.clipped(3, clipped) == 1.0
    assert unwrapper.clipped(3, unclipped) == 1.0   # frame 3: its first level, not found again
    assert unwrapper.clipped(4, unclipped) is None
    assert unwrapper.clipped(5, clipped) == 1.0


def test_a_feature_poor_wall_keeps_its_axial_scale(tmp_path: Path, simulate_small) -> None:
    """Brushed aluminium at 1224 x 1024, whose texture is as weak as the sensor noise:
    the run's z follows the simulator's to 0.03 % (issue target). The patch shifts read
    short by ~0.02 px a link there from the strips' own noise (mosaic/noise.py), which
    left these 30 pairs 0.07 % short before its correction."""
    from pipestitch.pipeline.run import run_dataset

    root = simulate_small(tmp_path / "ds", "--scenario", "aluminium", "--pairs", "30",
                          "--seed", "1")
    run_dataset(root, tmp_path / "out", show_progress=False)
    ours = read_csv_columns(tmp_path / "out" / "poses.csv", ["z_mm"])["z_mm"]
    truth = read_csv_columns(root / "truth" / "poses.csv", ["z_mm"])["z_mm"]
    assert np.isfinite(ours).all()
    slope = np.polyfit(truth, ours, 1)[0]
    assert abs(slope - 1) <= 3e-4


def _link(i: int, j: int, dz_mm: float, droll_deg: float = 0.0) -> Link:
    return Link(i, j, dz_mm, droll_deg, 0.5, 0.02, 0.01)


def test_an_undecided_frame_s_links_yield_to_the_odometer(monkeypatch) -> None:
    # 20 mm steps, odometer good to 0.3 mm. Frame 4 was undecided; on its wrong mirror
    # its strip is warped and its links to 3 and 5 are precise but 2.5 mm off. Its other
    # hypothesis' link to frame 3 put it 2.4 mm elsewhere: that is its links' sigma once
    # the solve has given up the odometer for them.
    rng = np.random.default_rng(0)
    truth = 20.0 * np.arange(10)
    odometry = {f: float(truth[f] + rng.normal(0, 0.3)) for f in range(10)}
    links = [_link(f, f + 1, 20.0 + (2.5 if f == 3 else -2.5 if f == 4 else 0.0))
             for f in range(9)]
    chosen, other = [(links[3], None)], [(_link(3, 4, 20.1, 0.4), None)]
    spread = _mirror_spread([chosen, other])
    assert spread == pytest.approx((2.4, 0.4))
    assert _mirror_spread([chosen, [(_link(2, 4, 40.0), None)]]) is None   # nothing common
    dataset = SimpleNamespace(n_pairs=10, odometry_mm=odometry)

    def z_error(spread_of: dict) -> float:
        reg = SimpleNamespace(links=links, done=list(range(10)), spread=spread_of)
        z = _solved(dataset, reg).z_mm
        return float(np.max(np.abs(z - z[0] - truth)))

    assert z_error({}) > 2.0              # the precise links outvote the odometer
    assert z_error({4: spread}) < 1.0     # the odometer places frame 4
    # links that agree with the odometer keep their sigma, undecided frame or not
    agreeing = [_link(f, f + 1, truth[f + 1] - truth[f]) for f in range(9)]
    with_spread, without = (
        _solved(dataset, SimpleNamespace(links=agreeing, done=list(range(10)), spread=s)).z_mm
        for s in ({4: spread}, {}))
    np.testing.assert_array_equal(with_spread, without)
    # every frame undecided, far apart in its two hypotheses: the re-solve is given the
    # odometer's noise as the unwidened links measured it (widened links would raise its
    # floor, their median sigma)
    # z then follows the odometer, whose readings are 0.3 mm noisy and whose scale is
    # fitted (0.66 mm here)
    wide = {f: (20.0, 5.0) for f in range(10)}
    assert z_error(wide) < 1.0
    calls = []

    def spy(*args, **kwargs):
        calls.append(kwargs.get("odometer_sigma_mm"))
        return solve_positions(*args, **kwargs)

    monkeypatch.setattr(stitching, "solve_positions", spy)
    _solved(dataset, SimpleNamespace(links=links, done=list(range(10)), spread=wide))
    assert calls == [None, pytest.approx(odometer_noise_mm(links, odometry))]
