"""Video input: lossless round trips, laser/LED pairing by content, dropped and
undecodable frames (the pairs keep their place in the recording), timestamps, random
access, bad input, and `run`/`pose --video` against the frames."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.errors import DatasetError
from pipestitch.io.dataset import open_dataset
from pipestitch.io.video import (
    VideoReader,
    classify_laser_frames,
    frame_brightness,
    pair_frames,
    write_video,
)

H, W = 96, 128


def _laser(k: int, dtype=np.uint8, colour: bool = False) -> np.ndarray:
    """Dark frame with a thin bright ring (radius varies with k) and sensor noise."""
    top = np.iinfo(dtype).max
    rng = np.random.default_rng(k)
    img = rng.integers(0, max(2, top // 60), (H, W)).astype(np.float64)
    cv2.circle(img, (W // 2, H // 2), 30 + k % 5, 0.9 * top, 2)
    img = img.astype(dtype)
    return np.dstack([img, img // 2, img]) if colour else img


def _led(k: int, dtype=np.uint8, colour: bool = False) -> np.ndarray:
    """Lit wall: a random texture at mid to high brightness."""
    top = np.iinfo(dtype).max
    rng = np.random.default_rng(1000 + k)
    img = (rng.uniform(0.3, 0.9, (H, W)) * top).astype(dtype)
    return np.dstack([img, rng.permutation(img), img]) if colour else img


def _interleaved(n_pairs: int, laser_first: bool = True, **kw) -> list[np.ndarray]:
    out = []
    for k in range(n_pairs):
        pair = [_laser(k, **kw), _led(k, **kw)]
        out += pair if laser_first else pair[::-1]
    return out


@pytest.mark.parametrize("codec", ["ffvhuff", "ffv1"])
@pytest.mark.parametrize("dtype,colour", [(np.uint8, False), (np.uint16, False),
                                          (np.uint8, True), (np.uint16, True)])
def test_video_round_trip_is_lossless_with_random_access(tmp_path: Path, dtype,
                                                         colour: bool, codec: str) -> None:
    frames = _interleaved(6, dtype=dtype, colour=colour)
    path = write_video(tmp_path / "v.vid", frames, fps=25.0, codec=codec)
    reader = VideoReader(path)
    assert reader.n_frames == len(frames)
    np.testing.assert_allclose(reader.index.time_s, np.arange(len(frames)) / 25.0, atol=1e-3)
    order = np.random.default_rng(0).permutation(len(frames)).tolist() + [0, 1, 11, 2]
    for k in order:  # out of order: seeks backwards and forwards, cache hits
        got = reader.frame(k)
        assert got.dtype == frames[k].dtype and got.shape == frames[k].shape
        assert np.array_equal(got, frames[k]), k
    reader.close()


def test_brightness_classifies_laser_frames_without_a_threshold() -> None:
    # Two exposures (x 1/3) in one run: what matters is the two populations, not a level.
    frames = _interleaved(5) + [(f // 3).astype(np.uint8) for f in _interleaved(5)]
    truth = np.array([k % 2 == 0 for k in range(len(frames))])
    got = classify_laser_frames(np.array([frame_brightness(f) for f in frames]))
    assert np.array_equal(got, truth)
    with pytest.raises(ValueError, match="equally bright"):
        classify_laser_frames(np.full(6, 0.2))


def test_pairing_resyncs_after_dropped_frames_and_reports_them() -> None:
    # LED-first video: (E L)(E L)(E -)(E L)(- L)(E L) -> frames 5 and 8 of the recording
    # missing; the video's frames 0-9 are the recording's 0-4, 6, 7, 9-11.
    sequence = "ELELE" + "EL" + "L" + "EL"
    is_laser = np.array([c == "L" for c in sequence])
    pairs = pair_frames(is_laser)
    assert not pairs.laser_first
    # Independently worked out: frame numbers of each pair's laser and LED frames; pair 2
    # (no laser frame) keeps its number, so pairs 3-5 keep theirs.
    assert pairs.laser.tolist() == [1, 3, -1, 6, 7, 9]
    assert pairs.led.tolist() == [0, 2, 4, 5, -1, 8]
    assert pairs.messages == (
        "frame 4: LED frame without its laser frame (dropped or undecodable); pair 2 has no "
        "laser frame",
        "frame 7: laser frame without its LED frame (dropped or undecodable); pair 4 has no "
        "LED frame")


def _recording(n_pairs: int, dropped: set[int], *, inside_s: float = 0.03,
               pair_s: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """is_laser and timestamps of a laser-first recording (its frame 2i is pair i's laser
    frame, taken at i * pair_s; the LED frame inside_s later) without frames ``dropped``."""
    keep = [k for k in range(2 * n_pairs) if k not in dropped]
    return (np.array([k % 2 == 0 for k in keep]),
            np.array([(k // 2) * pair_s + (k % 2) * inside_s for k in keep]))


@pytest.mark.parametrize("inside_s,pair_s", [(0.05, 0.1), (0.03, 0.5), (0.47, 0.5)])
def test_pairs_keep_their_place_in_the_recording_whatever_the_spacing(inside_s: float,
                                                                      pair_s: float) -> None:
    # Evenly spaced frames, and a probe that takes its two frames 30 ms apart every 0.5 s
    # (or 470 ms apart): the timestamps' uneven steps are not dropped frames.
    # Dropped: pair 3 whole (frames 6, 7), pair 5's LED (11), pair 8's laser (16).
    is_laser, time_s = _recording(10, {6, 7, 11, 16}, inside_s=inside_s, pair_s=pair_s)
    pairs = pair_frames(is_laser, time_s)
    assert pairs.laser_first
    # Worked out from the recording: its frame k is the video's k, k - 2, k - 3, k - 4
    # after each drop.
    assert pairs.laser.tolist() == [0, 2, 4, -1, 6, 8, 9, 11, -1, 14]
    assert pairs.led.tolist() == [1, 3, 5, -1, 7, -1, 10, 12, 13, 15]
    assert len(pairs.messages) == 3
    assert pairs.messages[0].startswith("frames 5-6: timestamp gap of ")
    assert pairs.messages[0].endswith("2 frame(s) dropped; pair 3 has no frame")
    assert pairs.messages[1] == (f"frame 8 ({5 * pair_s:.3f} s): laser frame without its LED "
                                 "frame (dropped or undecodable); pair 5 has no LED frame")
    assert pairs.messages[2].startswith("frame 13 (")
    assert pairs.messages[2].endswith("LED frame without its laser frame (dropped or "
                                      "undecodable); pair 8 has no laser frame")
    # Without timestamps only the alternation shows where frames are missing: the whole
    # pair cannot be seen, the single frames still keep the pairs after them in place.
    alone = pair_frames(is_laser)
    assert alone.laser.tolist() == [0, 2, 4, 6, 8, 9, 11, -1, 14]
    assert alone.led.tolist() == [1, 3, 5, 7, -1, 10, 12, 13, 15]


def test_a_video_that_starts_or_jumps_oddly_is_numbered_from_its_first_frame() -> None:
    # The first frame is an LED frame of a laser-first video: pair 0 lost its laser frame.
    is_laser, time_s = _recording(4, {0})
    pairs = pair_frames(is_laser, time_s)
    assert pairs.laser_first
    assert pairs.laser.tolist() == [-1, 1, 3, 5] and pairs.led.tolist() == [0, 2, 4, 6]
    assert pairs.messages == ("frame 0 (0.030 s): LED frame without its laser frame (dropped "
                              "or undecodable); pair 0 has no laser frame",)
    # A timestamp jump longer than the whole video (a clock reset, joined files) is not
    # read as thousands of dropped pairs; it is reported.
    is_laser, time_s = _recording(6, set())
    time_s[6:] += 1000.0
    pairs = pair_frames(is_laser, time_s)
    assert pairs.laser.tolist() == [0, 2, 4, 6, 8, 10]
    assert pairs.messages == ("frames 5-6: timestamp jump of 1000 s, longer than the video: "
                              "not counted as dropped frames",)


def test_dropped_frames_in_a_video_give_pairs_timestamps_and_gaps(tmp_path: Path) -> None:
    frames = _interleaved(6)
    keep = [k for k in range(12) if k not in (3, 6, 7)]  # one LED, then a whole pair
    path = write_video(tmp_path / "v.avi", [frames[k] for k in keep], fps=20.0,
                       frame_numbers=keep)
    root = _dataset_root(tmp_path, W, H)
    ds = open_dataset(root, video=path)
    # Pairs 0-5 of the original run: 1 without its LED frame, 3 lost whole (no pose, but
    # its number stays taken, so odometry row 4 is still pair 4's).
    assert ds.n_pairs == 6
    assert ds.led_missing() == [1, 3]
    present = [0, 1, 2, 4, 5]
    np.testing.assert_allclose(ds.timestamps_s[present], [0.0, 0.1, 0.2, 0.4, 0.5], atol=1e-3)
    assert np.array_equal(ds.read_laser(4), frames[8])
    assert np.array_equal(ds.read_led(5), frames[11])
    with pytest.raises(DatasetError, match="pair 1: LED frame missing"):
        ds.read_led(1)
    with pytest.raises(DatasetError, match="frame missing from the video"):
        ds.read_laser(3)
    assert ds.notes == ["frame 2 (0.100 s): laser frame without its LED frame (dropped or "
                        "undecodable); pair 1 has no LED frame",
                        "frames 4-5: timestamp gap of 0.15 s, 2 frame(s) dropped; pair 3 has no "
                        "frame"]


def _damage(path: Path, out: Path, frames: set[int]) -> Path:
    """A copy of the video whose ``frames`` (0-based) hold 20 bytes of their packet: the
    decoder refuses them, as it does a frame damaged on the recorder's disk."""
    with av.open(str(path)) as src, av.open(str(out), "w", format="avi") as dst:
        s_in = src.streams.video[0]
        s_out = dst.add_stream_from_template(s_in)
        packets = (p for p in src.demux(s_in) if p.size)   # not the final flush packet
        for k, packet in enumerate(packets):
            if k in frames:
                cut = av.Packet(bytes(packet)[:20])
                cut.pts, cut.dts, cut.time_base = packet.pts, packet.dts, packet.time_base
                cut.is_keyframe = True
                packet = cut
            packet.stream = s_out
            dst.mux(packet)
    return out


@pytest.mark.parametrize("damaged,laser,led", [
    # frame 4 is pair 2's laser frame, frame 5 its LED frame
    (4, [0, 2, -1, 5, 7], [1, 3, 4, 6, 8]),
    (5, [0, 2, 4, 5, 7], [1, 3, -1, 6, 8]),
])
def test_an_undecodable_frame_is_reported_and_the_pairs_after_it_keep_their_numbers(
        tmp_path: Path, caplog, damaged: int, laser: list[int], led: list[int]) -> None:
    frames = _interleaved(5)
    path = _damage(write_video(tmp_path / "v.avi", frames, fps=20.0), tmp_path / "bad.avi",
                   {damaged})
    reader = VideoReader(path)
    assert reader.n_frames == 9
    where = f"between frames {damaged - 1} and {damaged}"
    assert reader.index.undecodable == (
        f"the frame at {damaged / 20:.3f} s ({where}) cannot be decoded (Invalid data found "
        "when processing input); skipped",)
    reader.close()
    caplog.clear()
    ds = open_dataset(_dataset_root(tmp_path, W, H), video=path)
    assert [r.getMessage() for r in caplog.records if "cannot be decoded" in r.getMessage()
            ] == [f"{path}: {reader.index.undecodable[0]}"]   # logged once, naming the frame
    assert ds.n_pairs == 5
    assert ds.pairs.laser.tolist() == laser and ds.pairs.led.tolist() == led
    kind = "laser" if damaged % 2 == 0 else "LED"
    assert ds.notes[0] == reader.index.undecodable[0]   # reported with the run's problems
    assert len(ds.notes) == 2 and ds.notes[1].endswith(f"pair 2 has no {kind} frame")
    for i in (0, 1, 3, 4):   # every other pair reads its own frames, at its own number
        assert np.array_equal(ds.read_laser(i), frames[2 * i])
        assert np.array_equal(ds.read_led(i), frames[2 * i + 1])
    with pytest.raises(DatasetError, match="missing"):
        ds.read_laser(2) if kind == "laser" else ds.read_led(2)
    ds.close()


def test_a_video_with_no_decodable_frame_is_bad_input(tmp_path: Path) -> None:
    path = _damage(write_video(tmp_path / "v.avi", _interleaved(2)), tmp_path / "bad.avi",
                   {0, 1, 2, 3})
    with pytest.raises(DatasetError, match="no frame that can be decoded: Invalid data"):
        VideoReader(path)


def _dataset_root(tmp_path: Path, width: int, height: int) -> Path:
    root = tmp_path / "ds"
    root.mkdir(parents=True)
    (root / "probe.toml").write_text(
        "[camera]\nmodel = \"opencv_fisheye\"\n"
        f"width = {width}\nheight = {height}\n"
        f"K = [[40.0, 0.0, {width / 2 - 0.5}], [0.0, 40.0, {height / 2 - 0.5}], [0, 0, 1]]\n"
        "D = [0.0, 0.0, 0.0, 0.0]\n"
        "[laser]\nplane_distance_mm = 16.0\n[probe]\nlength_mm = 145.0\ndiameter_mm = 45.0\n"
        "[pipe]\ninner_diameter_mm = 65.0\n", encoding="utf-8")
    return root


def test_bad_videos_are_reported_naming_the_file(tmp_path: Path) -> None:
    root = _dataset_root(tmp_path, W, H)
    with pytest.raises(DatasetError, match="video file not found") as info:
        open_dataset(root, video=tmp_path / "missing.mkv")
    assert info.value.path == tmp_path / "missing.mkv"
    junk = tmp_path / "junk.mkv"
    junk.write_text("not a video")
    with pytest.raises(DatasetError, match="cannot open as a video"):
        open_dataset(root, video=junk)
    flat = write_video(tmp_path / "flat.avi", [np.full((H, W), 90, np.uint8)] * 4)
    with pytest.raises(DatasetError, match="equally bright"):
        open_dataset(root, video=flat)
    wrong = _dataset_root(tmp_path / "w", W * 2, H)
    ds = open_dataset(wrong, video=write_video(tmp_path / "v.avi", _interleaved(2)))
    with pytest.raises(DatasetError, match=r"probe\.toml says"):
        ds.read_laser(0)


@pytest.fixture(scope="module")
def simulated_video(tmp_path_factory, simulate_small) -> tuple[Path, Path]:
    """A small simulated dataset and its frames written as a video (laser first)."""
    tmp = tmp_path_factory.mktemp("video")
    root = simulate_small(tmp / "ds", "--scenario", "default", "--pairs", "3")
    ds = open_dataset(root)
    frames = (f for i in range(ds.n_pairs) for f in (ds.read_laser(i), ds.read_led(i)))
    return root, write_video(tmp / "run.avi", frames)


def test_pose_from_a_video_with_a_damaged_frame_keeps_every_row_in_place(
        tmp_path: Path, caplog, simulated_video) -> None:
    """Pair 1's laser frame undecodable: poses.csv still has rows 0, 1, 2, row 1 says why
    it has no pose, and row 2 is pair 2 (its odometry z, its own ring)."""
    import csv

    root, video = simulated_video
    damaged = _damage(video, tmp_path / "damaged.avi", {2})
    runner = CliRunner()
    rows = {}
    for name, extra in (("frames", []), ("video", ["--video", str(damaged)])):
        result = runner.invoke(app, ["pose", str(root), "--out", str(tmp_path / name),
                                     "--quiet", *extra])
        assert result.exit_code == 0, result.output
        with (tmp_path / name / "poses.csv").open(newline="") as handle:
            rows[name] = list(csv.DictReader(handle))
    assert "pair 1 has no laser frame" in result.output
    assert any("between frames 1 and 2) cannot be decoded" in r.getMessage()
               for r in caplog.records)
    assert [r["frame"] for r in rows["video"]] == ["0", "1", "2"]
    assert rows["video"][1]["alpha_deg"] == "nan"
    assert "frame missing from the video" in rows["video"][1]["error"]
    for i in (0, 2):
        for column in ("z_mm", "radius_mm", "rms_px"):
            assert rows["video"][i][column] == rows["frames"][i][column], (i, column)
        # the mirror pair is the ring's; which one is chosen may use the neighbours
        assert ({rows["video"][i]["alpha_deg"], rows["video"][i]["alt_alpha_deg"]}
                == {rows["frames"][i]["alpha_deg"], rows["frames"][i]["alt_alpha_deg"]})


def test_video_dataset_matches_the_frames_dataset(simulated_video) -> None:
    root, video = simulated_video
    frames_ds, video_ds = open_dataset(root), open_dataset(root, video=video)
    assert video_ds.n_pairs == frames_ds.n_pairs == 3
    assert video_ds.has_led and video_ds.led_missing() == []
    assert video_ds.odometry_mm == frames_ds.odometry_mm
    for i in (2, 0, 1):
        assert np.array_equal(video_ds.read_laser(i), frames_ds.read_laser(i))
        assert np.array_equal(video_ds.read_led(i), frames_ds.read_led(i))


def test_cli_run_and_pose_with_video_match_the_frames(tmp_path: Path, simulated_video) -> None:
    root, video = simulated_video
    runner = CliRunner()
    outs = {}
    for name, extra in (("frames", []), ("video", ["--video", str(video)])):
        outs[name] = tmp_path / name
        result = runner.invoke(app, ["run", str(root), "--out", str(outs[name]), "--quiet",
                                     *extra])
        assert result.exit_code == 0, result.output
    for name in ("poses.csv", "profile.csv", "defects.csv"):
        assert (outs["video"] / name).read_text() == (outs["frames"] / name).read_text(), name
    a = cv2.imread(str(outs["frames"] / "mosaic.png"), cv2.IMREAD_UNCHANGED)
    b = cv2.imread(str(outs["video"] / "mosaic.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(a, b)
    result = runner.invoke(app, ["pose", str(root), "--out", str(tmp_path / "p"), "--quiet",
                                 "--video", str(video)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["run", str(root), "--out", str(tmp_path / "x"),
                                 "--video", str(tmp_path / "nope.mkv")])
    assert result.exit_code == 2
    assert "nope.mkv" in result.output and "video file not found" in result.output


def test_check_with_a_video(tmp_path: Path) -> None:
    """`pipestitch check DATASET --video FILE`: dropped frames are warnings, a frame
    size other than probe.toml's and a missing video are errors naming the file."""
    from typer.testing import CliRunner

    from pipestitch.cli.app import app

    frames = _interleaved(4)
    keep = [k for k in range(8) if k != 3]                 # pair 1's LED frame dropped
    video = write_video(tmp_path / "v.avi", [frames[k] for k in keep], frame_numbers=keep)
    root = _dataset_root(tmp_path, W, H)
    runner = CliRunner()
    result = runner.invoke(app, ["check", str(root), "--video", str(video), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "without its LED frame" in result.output and "warning" in result.output
    wrong = _dataset_root(tmp_path / "w", W * 2, H)
    result = runner.invoke(app, ["check", str(wrong), "--video", str(video), "--quiet"])
    assert result.exit_code == 2 and "probe.toml says" in result.output
    result = runner.invoke(app, ["check", str(root), "--video", str(tmp_path / "no.avi")])
    assert result.exit_code == 2 and "video file not found" in result.output


def test_a_video_declaring_more_pixels_than_the_budget_is_not_decoded(tmp_path: Path,
                                                                     monkeypatch) -> None:
    import pipestitch.io.images as images

    path = write_video(tmp_path / "v.vid", _interleaved(2), fps=25.0)
    height, width = _interleaved(1)[0].shape[:2]
    monkeypatch.setattr(images, "MAX_PIXELS", width * height - 1)   # one pixel short
    with pytest.raises(DatasetError, match=r"declares .* pixels a frame.*not decoded"):
        VideoReader(path)


def test_an_undecodable_frame_reaches_the_notes_and_a_pair_without_laser_has_no_time(
        tmp_path: Path, caplog) -> None:
    """The decoder's refusal is the first of the dataset's notes (what run and pose list
    as "video: ..." problems), logged once; the pair that lost its laser frame has no
    timestamp rather than another frame's."""
    frames = _interleaved(5)
    path = _damage(write_video(tmp_path / "v.avi", frames, fps=20.0), tmp_path / "bad.avi",
                   {4})   # pair 2's laser frame
    caplog.clear()
    ds = open_dataset(_dataset_root(tmp_path, W, H), video=path)
    assert len(ds.notes) == 2
    assert ds.notes[0] == ("the frame at 0.200 s (between frames 3 and 4) cannot be decoded "
                           "(Invalid data found when processing input); skipped")
    assert ds.notes[1].endswith("pair 2 has no laser frame")
    assert sum("cannot be decoded" in r.getMessage() for r in caplog.records) == 1
    # laser frames at 0.05 s a frame: pairs 0, 1, 3, 4 at 0, 0.1, 0.3, 0.4 s
    assert np.isnan(ds.timestamps_s[2])
    np.testing.assert_allclose(ds.timestamps_s[[0, 1, 3, 4]], [0.0, 0.1, 0.3, 0.4], atol=1e-9)
    ds.close()


def test_pairs_lost_whole_have_no_timestamp(tmp_path: Path) -> None:
    frames = _interleaved(6)
    keep = [k for k in range(12) if k not in (6, 7)]   # pair 3 lost whole
    path = write_video(tmp_path / "v.avi", [frames[k] for k in keep], fps=20.0,
                       frame_numbers=keep)
    ds = open_dataset(_dataset_root(tmp_path, W, H), video=path)
    assert ds.pairs.laser.tolist() == [0, 2, 4, -1, 6, 8]
    assert np.isnan(ds.timestamps_s[3])   # not the time of the video's last frame (0.55 s)
    np.testing.assert_allclose(ds.timestamps_s[[0, 1, 2, 4, 5]], [0.0, 0.1, 0.2, 0.4, 0.5],
                               atol=1e-9)
    ds.close()


def test_check_a_video_whose_first_pair_lost_its_laser_frame(tmp_path: Path) -> None:
    """Pair 0 without its laser frame (the video starts on an LED frame): check reads
    the first frame there is for the frame size, as run does not need pair 0's laser."""
    frames = _interleaved(4)
    keep = list(range(1, 8))
    video = write_video(tmp_path / "v.avi", [frames[k] for k in keep], fps=20.0,
                        frame_numbers=keep)
    root = _dataset_root(tmp_path, W, H)
    ds = open_dataset(root, video=video)
    assert ds.pairs.laser.tolist() == [-1, 1, 3, 5]
    ds.close()
    result = runner_check(root, video)
    assert result.exit_code == 0, result.output
    assert "pair 0 has no laser frame" in result.output and "warning" in result.output
    wrong = _dataset_root(tmp_path / "w", W * 2, H)
    result = runner_check(wrong, video)
    assert result.exit_code == 2 and "probe.toml says" in result.output


def test_check_lists_an_undecodable_frame(tmp_path: Path) -> None:
    video = _damage(write_video(tmp_path / "v.avi", _interleaved(4), fps=20.0),
                    tmp_path / "bad.avi", {3})
    result = runner_check(_dataset_root(tmp_path, W, H), video)
    assert result.exit_code == 0, result.output
    assert "cannot be decoded" in result.output and "warning" in result.output


def runner_check(root: Path, video: Path):
    return CliRunner().invoke(app, ["check", str(root), "--video", str(video), "--quiet"])


@pytest.mark.parametrize("damaged", [{0}, {0, 1}, {0, 1, 2}])
def test_a_video_whose_first_frames_cannot_be_decoded_keeps_its_pair_numbers(
        tmp_path: Path, damaged: set[int]) -> None:
    """The refused packets' timestamps say where the recording starts: the first decoded
    frame is not taken for frame 0 of the recording (every pair would be one off)."""
    frames = _interleaved(5)
    path = _damage(write_video(tmp_path / "v.avi", frames, fps=20.0), tmp_path / "bad.avi",
                   damaged)
    ds = open_dataset(_dataset_root(tmp_path, W, H), video=path)
    assert ds.n_pairs == 5
    first = max(damaged) + 1
    for i in range(first // 2 + (first % 2), 5):   # pairs with both frames decodable
        assert np.array_equal(ds.read_laser(i), frames[2 * i])
        assert np.array_equal(ds.read_led(i), frames[2 * i + 1])
    lost = [i for i in range(5) if 2 * i in damaged]
    assert [i for i in range(5) if ds.pairs.laser[i] < 0] == lost
    assert any("pair 0 has" in note or "pairs 0-" in note for note in ds.notes), ds.notes
    ds.close()


def test_leading_frames_are_counted_by_the_packets_refused_before_the_first_decoded() -> None:
    """The recording's first two frames refused: counted from the timestamps, never more
    than the packets refused there (a stray early timestamp adds no pairs)."""
    is_laser, time_s = _recording(4, {0, 1}, inside_s=0.05, pair_s=0.1)
    right = pair_frames(is_laser, time_s, start_s=0.0, refused_before=2)
    assert right.laser.tolist() == [-1, 0, 2, 4] and right.led.tolist() == [-1, 1, 3, 5]
    stray = pair_frames(is_laser, time_s, start_s=-1000.0, refused_before=2)
    assert stray.laser.tolist() == right.laser.tolist()


def test_a_video_cut_short_is_said_so_and_names_itself_against_the_odometer(
        tmp_path: Path) -> None:
    """A file cut short (a copy or a recording that stopped) decodes to fewer frames than
    its container declares: `check` warns of the frames missing at the end, and an
    odometry.csv with rows for the lost pairs is an error that names the video and how
    many pairs it holds (it used to blame odometry.csv alone)."""
    whole = write_video(tmp_path / "v.mkv", _interleaved(12), codec="ffv1")
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])
    with av.open(str(whole)) as full:
        declared_s = full.duration / 1e6
    decoded = VideoReader(cut).index
    assert decoded.time_s.size < 24
    lost = round(declared_s * 30) - decoded.time_s.size   # 30 frames/s: write_video's
    assert any(f"about {lost} frame(s) missing at the end" in line
               for line in decoded.undecodable), decoded.undecodable
    assert not any("missing at the end" in line for line in VideoReader(whole).index.undecodable)
    root = _dataset_root(tmp_path, W, H)
    runner = CliRunner()
    result = runner.invoke(app, ["check", str(root), "--video", str(cut), "--quiet"])
    assert result.exit_code == 0 and "the file cut short?" in result.output, result.output
    (root / "odometry.csv").write_text("frame,z_mm\n" + "".join(f"{k},{5.0 * k}\n"
                                                                 for k in range(12)))
    result = runner.invoke(app, ["check", str(root), "--video", str(cut), "--quiet"])
    pairs = decoded.time_s.size // 2
    assert result.exit_code == 2, result.output
    assert f"the video cut.mkv holds {pairs} pair(s)" in " ".join(result.output.split())


def test_an_audio_track_longer_than_the_video_is_not_a_cut(tmp_path: Path) -> None:
    """The container's length spans every stream: a recorder's voice track running on
    after the video is no sign of a cut (only the video stream's own length, or the
    container's when the video is all it holds, is compared with the frames)."""
    from fractions import Fraction

    path = tmp_path / "voice.mkv"
    with av.open(str(path), "w", format="matroska") as out:
        video = out.add_stream("ffv1", rate=30)
        video.width, video.height, video.pix_fmt = W, H, "gray"
        audio = out.add_stream("pcm_s16le", rate=8000)
        for k, image in enumerate(_interleaved(6)):
            frame = av.VideoFrame.from_ndarray(image, format="gray")
            frame.pts, frame.time_base = k, Fraction(1, 30)
            out.mux(video.encode(frame))
        out.mux(video.encode())
        for start in range(0, 8000, 1000):   # 1 s of silence against 0.4 s of video
            sound = av.AudioFrame.from_ndarray(np.zeros((1, 1000), np.int16), format="s16",
                                               layout="mono")
            sound.sample_rate, sound.pts, sound.time_base = 8000, start, Fraction(1, 8000)
            out.mux(audio.encode(sound))
        out.mux(audio.encode())
    with av.open(str(path)) as check:
        assert check.duration / 1e6 > 0.9   # the container declares the audio's second
    index = VideoReader(path).index
    assert index.time_s.size == 12
    assert not any("missing at the end" in line for line in index.undecodable), index.undecodable
