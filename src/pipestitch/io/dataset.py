"""Dataset folders (SPEC): opening, frame access and a full validation.

``open_dataset`` reads what every stage needs (probe.toml, the frame list,
odometry) and fails with a :class:`DatasetError` naming the file when that is not
possible. With ``video=FILE`` the frames come from a video of alternating laser/LED
frames instead of frames/ (:class:`VideoDataset`, same interface).
``check_dataset`` goes further and lists *every* problem it finds (numbering,
image sizes, unreadable images, CSV columns) without stopping at the first.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipestitch.camera import blank_frame, mean_level
from pipestitch.config import ProbeConfig
from pipestitch.errors import DatasetError
from pipestitch.io.frame_files import frame_files, frame_twins
from pipestitch.io.images import read_image
from pipestitch.io.mask import mask_notes, mask_path, read_mask
from pipestitch.io.probe_toml import read_probe_toml
from pipestitch.io.video import VideoReader, classify_laser_frames, pair_frames

__all__ = [
    "TRUTH_POSE_COLUMNS",
    "Dataset",
    "Problem",
    "VideoDataset",
    "check_dataset",
    "check_frame_column",
    "check_odometry_and_imu",
    "count_frame_files",
    "laser_brighter",
    "open_dataset",
    "read_csv_columns",
    "read_csv_lines",
    "read_frame",
    "read_odometry",
    "swapped_note",
]

ODOMETRY_FILE = "odometry.csv"
TRUTH_POSE_COLUMNS = ("frame", "alpha_deg", "beta_deg", "dx_mm", "dy_mm", "z_mm", "roll_deg")


@dataclass(frozen=True)
class Problem:
    """One finding of :func:`check_dataset`."""

    path: Path
    message: str
    severity: str = "error"  # "error" | "warning"

    def __str__(self) -> str:
        return f"{self.severity}: {self.path}: {self.message}"


@dataclass
class Dataset:
    """An opened dataset: configuration and frame paths (images are read lazily)."""

    root: Path
    config: ProbeConfig
    laser_paths: list[Path]
    led_paths: list[Path | None] = field(default_factory=list)
    odometry_mm: dict[int, float] | None = None
    odometry_notes: list[str] = field(default_factory=list)   # warnings about odometry.csv

    @property
    def n_pairs(self) -> int:
        """Number of frame pairs (laser frames)."""
        return len(self.laser_paths)

    @property
    def has_led(self) -> bool:
        """True when the dataset has LED frames (some pairs may still lack one)."""
        return any(p is not None for p in self.led_paths)

    def led_missing(self) -> list[int]:
        """Pairs whose LED frame is missing in a dataset that has LED frames."""
        if not self.has_led:
            return []
        return [i for i, p in enumerate(self.led_paths) if p is None]

    def read_laser(self, index: int) -> np.ndarray:
        """Laser frame ``index`` as stored (raises DatasetError naming the file)."""
        return self._checked(self.laser_paths[index])

    def read_led(self, index: int) -> np.ndarray:
        """LED frame ``index`` as stored (a missing one is named as its laser frame is
        stored: ``led_00011.tif`` beside ``laser_00011.tif``)."""
        path = self.led_paths[index] if index < len(self.led_paths) else None
        if path is None:
            suffix = self.laser_paths[index].suffix if index < len(self.laser_paths) else ".png"
            raise DatasetError(self.root / "frames" / f"led_{index:05d}{suffix}",
                               "LED frame missing")
        return self._checked(path)

    def _checked(self, path: Path) -> np.ndarray:
        return read_frame(path, (self.config.camera.width, self.config.camera.height))

    def close(self) -> None:
        """Nothing to release for frame files (a video dataset closes its decoder)."""


def read_frame(path: Path, size: tuple[int, int]) -> np.ndarray:
    """Read a frame and check its size (width, height) and channel count.

    Raises
    ------
    DatasetError
        Naming the file: unreadable, wrong size or an unusable number of channels.
    """
    img = read_image(path, size=size)   # the size checked before decoding (io.images)
    if img.ndim == 3 and img.shape[2] not in (3, 4):
        raise DatasetError(path, f"expected 1, 3 or 4 channels, got {img.shape[2]}")
    return img


def _numbering_problems(kind: str, frames: dict[int, Path], frames_dir: Path) -> list[Problem]:
    if not frames:
        return []
    missing = sorted(set(range(max(frames) + 1)) - set(frames))
    if not missing:
        return []
    shown = ", ".join(f"{kind}_{i:05d}" for i in missing[:10])
    more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
    return [Problem(frames_dir, f"{kind} frames must be numbered contiguously from 00000; "
                                f"missing {shown}{more}")]


def read_csv_columns(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Read a numeric CSV with a header; every required column must be present.

    A UTF-8 byte-order mark (what spreadsheets write) is accepted.

    Raises
    ------
    DatasetError
        Naming the file and the line for missing columns or non-numeric values.
    """
    return read_csv_lines(path, required)[0]


def read_csv_lines(path: Path, required: tuple[str, ...], *, unread: tuple[str, ...] = ()
                   ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`read_csv_columns` and the line number (1-based) of every row read.

    ``unread``: required columns whose cell may say that nothing was read there (``nan``
    or empty, as SPEC's outputs write a value not measured): read as NaN; an infinite
    value or text is still an error.
    """
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(path, f"cannot read: {exc}") from exc
    if not rows:
        raise DatasetError(path, "empty file (expected a header line)")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise DatasetError(path, f"missing column(s) {', '.join(missing)}; header is {header}")
    cols: dict[str, list[float]] = {c: [] for c in header}
    lines: list[int] = []
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise DatasetError(path, f"line {lineno}: {len(row)} fields, header has {len(header)}")
        for name, cell in zip(header, row, strict=True):
            try:
                value = float(cell)
            except ValueError:
                value = math.nan if name not in required or (
                    name in unread and not cell.strip()) else None
            if value is None or (name in required and not math.isfinite(value)
                                 and not (name in unread and math.isnan(value))):
                raise DatasetError(path, f"line {lineno}: {name} = {cell!r} is not a finite number")
            cols[name].append(value)
        lines.append(lineno)
    return {k: np.asarray(v) for k, v in cols.items()}, np.asarray(lines, dtype=np.int64)


def check_frame_column(path: Path, frames: np.ndarray, lines: np.ndarray,
                       n_pairs: int | None = None, pairs_from: str = "") -> None:
    """Frame numbers of a per-frame CSV: whole numbers >= 0 (below ``n_pairs`` when
    given), each listed once. ``pairs_from`` says where the pairs were counted (a
    video cut short shows as rows beyond its pairs: the message names it).

    Raises
    ------
    DatasetError
        Naming the file and the first line at fault.
    """
    top = math.inf if n_pairs is None else n_pairs
    bad = np.flatnonzero((frames != np.round(frames)) | (frames < 0) | (frames >= top))
    if bad.size:
        k = int(bad[0])
        expected = "whole numbers >= 0" if n_pairs is None else f"integers in 0..{n_pairs - 1}"
        expected += f": {pairs_from}" if pairs_from and frames[k] >= top else ""
        raise DatasetError(path, f"frame numbers must be {expected} (line {lines[k]}: "
                                 f"frame {frames[k]:g})")
    first_line: dict[int, int] = {}
    for frame, line in zip(frames.astype(np.int64).tolist(), lines.tolist(), strict=True):
        if frame in first_line:
            raise DatasetError(path, f"line {line}: frame {frame} is listed more than once "
                                     f"(first on line {first_line[frame]})")
        first_line[frame] = line


def read_odometry(path: Path, n_pairs: int | None, pairs_from: str = ""
                  ) -> tuple[dict[int, float], list[str]]:
    """``odometry.csv``: z per frame, and the warnings about it.

    The one reader of the file (``open_dataset`` for every stage, ``check_dataset``).
    Warnings: frames without a reading (no row, or ``nan`` or an empty cell in z_mm: their
    z comes from registration alone) and z that does not move one way along the run.
    ``n_pairs`` None (the frames are unknown): frame numbers are not compared with the
    frames; ``pairs_from``: where the pairs were counted, for the message
    (:func:`check_frame_column`).

    Raises
    ------
    DatasetError
        Naming the file (and the line): missing columns, values that are neither
        numbers nor ``nan``/empty, frame numbers outside 0..n_pairs-1, a frame listed
        twice, no rows, no reading at all.
    """
    cols, lines = read_csv_lines(path, ("frame", "z_mm"), unread=("z_mm",))
    frames, z = cols["frame"], cols["z_mm"]
    if not len(frames):
        raise DatasetError(path, "no rows (expected frame,z_mm per frame)")
    check_frame_column(path, frames, lines, n_pairs, pairs_from)
    odometry = {int(f): float(v) for f, v in zip(frames, z, strict=True) if math.isfinite(v)}
    if not odometry:
        raise DatasetError(path, "no reading: z_mm is nan or empty on every row")
    return odometry, _odometry_notes(odometry, n_pairs)


def _odometry_notes(odometry: dict[int, float], n_pairs: int | None) -> list[str]:
    notes = []
    missing = sorted(set(range(n_pairs or 0)) - set(odometry))
    if missing:
        shown = ", ".join(str(i) for i in missing[:10])
        more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
        notes.append(f"no reading (no row, or z_mm nan or empty) for {len(missing)} frame(s) "
                     f"({shown}{more}): their z comes from registration alone")
    frames = sorted(odometry)
    steps = np.diff([odometry[f] for f in frames])
    if np.any(steps > 0) and np.any(steps < 0):
        ahead = np.sum(steps > 0) >= np.sum(steps < 0)
        k = int(np.flatnonzero(steps < 0 if ahead else steps > 0)[0])
        notes.append(f"z_mm is not monotonic: it goes {'back' if ahead else 'forward'} from "
                     f"frame {frames[k]} ({odometry[frames[k]]:g} mm) to frame "
                     f"{frames[k + 1]} ({odometry[frames[k + 1]]:g} mm)")
    return notes


class VideoDataset:
    """A dataset whose frames come from a video (same interface as :class:`Dataset`).

    Pairs are formed by content and numbered by their place in the recording
    (io.video): ``n_pairs`` counts those places, pairs whose frames are missing from the
    video included (a pair without its LED frame is in ``led_missing()``; reading a
    missing frame raises DatasetError). ``notes`` lists the frames the decoder refused,
    then the missing frames and timestamp gaps. ``timestamps_s[i]`` is the time of pair
    i's laser frame, NaN where it has none. ``laser_paths[i]`` is a pseudo path naming
    the video and the frame (for messages). Odometry frame numbers are pair numbers.
    """

    def __init__(self, root: Path, config: ProbeConfig, reader: VideoReader,
                 odometry_mm: dict[int, float] | None = None) -> None:
        self.root = root
        self.config = config
        self.reader = reader
        try:
            is_laser = classify_laser_frames(reader.index.brightness)
        except ValueError as exc:
            raise DatasetError(reader.path, str(exc)) from exc
        self.pairs = pair_frames(is_laser, reader.index.time_s, reader.index.start_s,
                                 reader.index.refused_before)
        if self.pairs.laser.size == 0:
            raise DatasetError(reader.path, "no laser frame found in the video")
        self.notes = [*reader.index.undecodable, *self.pairs.messages]
        has_laser = self.pairs.laser >= 0
        self.timestamps_s = np.full(self.pairs.laser.size, np.nan)
        self.timestamps_s[has_laser] = reader.index.time_s[self.pairs.laser[has_laser]]
        self.odometry_mm = odometry_mm
        self.odometry_notes: list[str] = []
        self.laser_paths = [self._name(k) for k in self.pairs.laser]
        self.led_paths = [self._name(k) if k >= 0 else None for k in self.pairs.led]

    def _name(self, frame: int) -> Path:
        return self.reader.path.with_name(f"{self.reader.path.name}#frame{frame}")

    @property
    def n_pairs(self) -> int:
        """Number of frame pairs: the places in the recording, from the first frame of the
        video to its last, those with a frame missing included."""
        return int(self.pairs.laser.size)

    @property
    def has_led(self) -> bool:
        """True when the video holds LED frames."""
        return bool(np.any(self.pairs.led >= 0))

    def led_missing(self) -> list[int]:
        """Pairs whose LED frame was dropped."""
        return [int(i) for i in np.flatnonzero(self.pairs.led < 0)] if self.has_led else []

    def read_laser(self, index: int) -> np.ndarray:
        """Laser frame of pair ``index`` (raises DatasetError naming the video)."""
        return self._checked(int(self.pairs.laser[index]))

    def read_led(self, index: int) -> np.ndarray:
        """LED frame of pair ``index``."""
        frame = int(self.pairs.led[index]) if index < self.n_pairs else -1
        if frame < 0:
            raise DatasetError(self.reader.path, f"pair {index}: LED frame missing (dropped)")
        return self._checked(frame)

    def _checked(self, frame: int) -> np.ndarray:
        img = self.reader.frame(frame)
        size = (self.config.camera.width, self.config.camera.height)
        if (img.shape[1], img.shape[0]) != size:
            raise DatasetError(self._name(frame), f"frame is {img.shape[1]}x{img.shape[0]}, "
                                                  f"probe.toml says {size[0]}x{size[1]}")
        return img

    def close(self) -> None:
        """Release the video decoder."""
        self.reader.close()


def open_dataset(root: str | Path, video: str | Path | None = None, *,
                 progress: Callable[[], None] | None = None) -> Dataset | VideoDataset:
    """Open a dataset folder: probe.toml, frame lists (or a video) and odometry.

    Parameters
    ----------
    root : str or Path
        Dataset folder (probe.toml, optional odometry.csv).
    video : str or Path, optional
        A video of alternating laser/LED frames used instead of frames/ (SPEC).
    progress : callable, optional
        Called once per video frame while the video is indexed.

    Raises
    ------
    DatasetError
        If the folder, probe.toml, the laser frames or the video are missing or
        malformed.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(root, "dataset folder not found")
    config = read_probe_toml(root / "probe.toml")
    if video is not None:
        return _open_video(root, config, Path(video), progress)
    frames_dir = root / "frames"
    if not frames_dir.is_dir():
        raise DatasetError(frames_dir, "frames/ folder not found")
    found, other = frame_files(frames_dir)
    for path, kept in frame_twins(found, other):
        raise DatasetError(path, TWIN_FRAME.format(other=kept.name))
    problems = _numbering_problems("laser", found["laser"], frames_dir)
    if problems:
        raise DatasetError(frames_dir, problems[0].message)
    if not found["laser"]:
        raise DatasetError(frames_dir, "no laser frames (expected frames/laser_00000.png, ...)")
    lasers = [found["laser"][i] for i in range(len(found["laser"]))]
    leds = [found["led"].get(i) for i in range(len(lasers))]
    dataset = Dataset(root=root, config=config, laser_paths=lasers, led_paths=leds)
    _attach_odometry(dataset)
    return dataset


def _attach_odometry(dataset: Dataset | VideoDataset) -> None:
    """Read ``odometry.csv`` (when present) into the dataset, its warnings into
    ``odometry_notes`` (the passes report them with the run's other messages)."""
    path = dataset.root / ODOMETRY_FILE
    if not path.is_file():
        return
    source = (f"the video {dataset.reader.path.name}" if isinstance(dataset, VideoDataset)
              else "frames/")
    dataset.odometry_mm, dataset.odometry_notes = read_odometry(
        path, dataset.n_pairs, pairs_held(source, dataset.n_pairs))


def pairs_held(source: str, n_pairs: int) -> str:
    """Where a dataset's pairs were counted, for a message about frame numbers."""
    return f"{source} holds {n_pairs} pair(s)"


def _open_video(root: Path, config: ProbeConfig, video: Path,
                progress: Callable[[], None] | None) -> VideoDataset:
    dataset = VideoDataset(root, config, VideoReader(video, progress=progress))
    _attach_odometry(dataset)
    for note in dataset.pairs.messages:   # the reader logged the undecodable frames
        logging.getLogger(__name__).warning("%s: %s", video, note)
    return dataset


def _check_images(paths: list[Path], size: tuple[int, int],
                  progress: Callable[[], None] | None,
                  levels: dict[Path, float]) -> Iterator[Problem]:
    """Each frame decoded: unreadable, of the wrong size or showing nothing; its mean
    level into ``levels``."""
    for path in paths:
        try:
            kind = path.name.split("_")[0]
            frame = read_frame(path, size)
            levels[path] = mean_level(frame)
            blank = _shows_nothing(frame, kind)
            if blank:   # read as a frame; pose and run take it as one that shows nothing
                yield Problem(path, f"{blank}: {BLANK_CONSEQUENCE[kind]}", "warning")
        except DatasetError as exc:
            yield Problem(path, exc.problem)
        if progress is not None:
            progress()


# A laser frame is dark but for its ring, or as bright as its LED frame where the LEDs
# (or daylight) light it too; an LED frame mistaken for one is an order of magnitude
# brighter than the laser frame taken for the LED frame. Twice: the middle, on a ratio
# scale, of the two.
SWAPPED_RATIO = 2.0
SWAPPED_NOTE = ("the laser frames are over twice as bright as their LED frames in {brighter} "
                "of {pairs} pairs (a laser frame is dark but for its ring): laser and LED "
                "frames swapped, or the pairs shifted by one frame?")


def laser_brighter(laser_level: float, led_level: float) -> bool:
    """Whether a pair's laser frame is over :data:`SWAPPED_RATIO` times as bright as its
    LED frame (their :func:`pipestitch.camera.mean_level`)."""
    return laser_level > SWAPPED_RATIO * led_level


def swapped_note(pairs_brighter: list[bool]) -> str:
    """:data:`SWAPPED_NOTE` when the laser frame is the brighter of its pair
    (:func:`laser_brighter`, one value per pair with both frames) in most of the pairs,
    else ""."""
    brighter = sum(pairs_brighter)
    if brighter <= len(pairs_brighter) / 2:
        return ""
    return SWAPPED_NOTE.format(brighter=brighter, pairs=len(pairs_brighter))


def _shows_nothing(frame: np.ndarray, kind: str) -> str:
    """Why ``frame`` shows nothing, or "". An LED frame: :func:`blank_frame`. A laser frame
    is dark but for a thin ring (a thousandth of its pixels, as many as blank_frame lets
    pass for hot pixels): only one whose every pixel is the same shows nothing."""
    if kind == "led":
        return blank_frame(frame)
    return blank_frame(frame) if float(np.ptp(frame)) == 0 else ""


TWIN_FRAME = "the same frame as {other}: keep one of the two files"
BLANK_CONSEQUENCE = {"laser": "no ring, the pair gets no pose",
                     "led": "the pose comes from the laser frame alone, not in the mosaic"}


def _check_frames(root: Path, config: ProbeConfig | None,
                  progress: Callable[[], None] | None) -> Iterator[Problem]:
    frames_dir = root / "frames"
    if not frames_dir.is_dir():
        yield Problem(frames_dir, "frames/ folder not found")
        return
    found, other = frame_files(frames_dir)
    twins = frame_twins(found, other)
    for path, kept in twins:
        yield Problem(path, TWIN_FRAME.format(other=kept.name))
    for path in sorted(set(other) - {p for p, _ in twins}):
        yield Problem(path, "not a frame name (expected laser_NNNNN.png or led_NNNNN.png)",
                      "warning")
    if not found["laser"]:
        yield Problem(frames_dir, "no laser frames (expected frames/laser_00000.png, ...)")
    yield from _numbering_problems("laser", found["laser"], frames_dir)
    if not found["led"]:
        yield Problem(frames_dir, "no LED frames: laser-only dataset (run gives poses, profile "
                                  "and report, no mosaic)", "warning")
    else:
        for i in sorted(set(found["laser"]) ^ set(found["led"])):
            if i in found["laser"]:   # as run takes it: that pair reported and not stitched
                yield Problem(frames_dir, f"pair {i:05d} has no led frame: its pose comes from "
                                          "the laser frame alone, it is not in the mosaic",
                              "warning")
            else:
                yield Problem(frames_dir, f"pair {i:05d} has no laser frame")
    yield from _repeated_frames(found)
    if config is not None:
        paths = [found[k][i] for k in ("laser", "led") for i in sorted(found[k])]
        levels: dict[Path, float] = {}
        yield from _check_images(paths, (config.camera.width, config.camera.height), progress,
                                 levels)
        pairs = [(levels.get(found["laser"][i]), levels.get(found["led"][i]))
                 for i in sorted(set(found["laser"]) & set(found["led"]))]
        if note := swapped_note([laser_brighter(laser, led) for laser, led in pairs
                                 if laser is not None and led is not None]):
            yield Problem(frames_dir, note, "warning")


def _repeated_frames(found: dict[str, dict[int, Path]]) -> Iterator[Problem]:
    """Frames whose file is byte for byte the one of the pair before: a camera or a
    conversion that repeated a frame (a probe standing still still has sensor noise).
    The pair is processed as it is; z and roll come out the same as the one before."""
    for files in found.values():
        for i in sorted(files):
            before = files.get(i - 1)
            if before is not None and _same_bytes(before, files[i]):
                yield Problem(files[i], f"the same file as {before.name} (a repeated frame: "
                                        "a stalled camera or a copy?)", "warning")


def _same_bytes(a: Path, b: Path) -> bool:
    """Whether two files hold the same bytes: sizes, then their first 64 kB (where an
    uncompressed TIFF's pixels start), then the whole."""
    try:
        if a.stat().st_size != b.stat().st_size:
            return False
        with a.open("rb") as fa, b.open("rb") as fb:
            if fa.read(1 << 16) != fb.read(1 << 16):
                return False
        return a.read_bytes() == b.read_bytes()
    except OSError:   # said where the file is read
        return False


def _check_truth(root: Path) -> Iterator[Problem]:
    truth = root / "truth"
    if not truth.is_dir():
        return
    checks = [("poses.csv", TRUTH_POSE_COLUMNS),
              ("defects.csv", ("z_mm", "theta_deg", "diameter_mm"))]
    for name, columns in checks:
        if (truth / name).is_file():
            try:
                read_csv_columns(truth / name, columns)
            except DatasetError as exc:
                yield Problem(truth / name, exc.problem)
    wall_json = truth / "wall.json"
    if wall_json.is_file():
        yield from _check_wall_json(wall_json)


WALL_JSON_KEYS = ("mm_per_px_axial", "deg_per_px", "z0_mm", "radius_mm")


def _check_wall_json(path: Path) -> Iterator[Problem]:
    """truth/wall.json: a JSON object holding the wall grid's keys."""
    try:
        meta = json.loads(path.read_text(encoding="utf-8-sig"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        yield Problem(path, f"malformed JSON: {exc}")
        return
    if not isinstance(meta, dict):
        yield Problem(path, f"expected a JSON object ({', '.join(WALL_JSON_KEYS)}), "
                            f"got {_json_kind(meta)}")
        return
    missing = set(WALL_JSON_KEYS) - set(meta)
    if missing:
        yield Problem(path, f"missing key(s) {', '.join(sorted(missing))}")


def _json_kind(value: object) -> str:
    """What a JSON value is, in JSON's words (for messages)."""
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    kinds = ((str, "a string"), (list, "an array"), ((int, float), "a number"))
    return next(name for kind, name in kinds if isinstance(value, kind))


def check_odometry_and_imu(root: Path, n_pairs: int | None, pairs_from: str = ""
                           ) -> list[Problem]:
    """odometry.csv and imu.csv read by the readers every stage uses: their errors, and
    the odometry warnings (missing rows, z not monotonic). ``n_pairs``: the number of
    frame pairs, None when unknown (no frames); ``pairs_from``: where they were counted
    (:func:`read_odometry`)."""
    from pipestitch.io.imu import IMU_FILE, read_imu  # imu reads its CSV with this module

    problems = []
    odo = root / ODOMETRY_FILE
    if odo.is_file():
        try:
            _, notes = read_odometry(odo, n_pairs, pairs_from)
            problems.extend(Problem(odo, note, "warning") for note in notes)
        except DatasetError as exc:
            problems.append(Problem(odo, exc.problem))
    try:
        read_imu(root)
    except DatasetError as exc:
        problems.append(Problem(exc.path or root / IMU_FILE, exc.problem))
    return problems


def count_frame_files(root: str | Path) -> int:
    """How many frame images ``check_dataset`` will decode (for a progress bar)."""
    frames_dir = Path(root) / "frames"
    if not frames_dir.is_dir():
        return 0
    found, _ = frame_files(frames_dir)
    return len(found["laser"]) + len(found["led"])


def check_dataset(root: str | Path, *,
                  progress: Callable[[], None] | None = None) -> list[Problem]:
    """Validate a dataset and return every problem found (empty list: valid).

    Parameters
    ----------
    root : str or Path
        Dataset folder.
    progress : callable, optional
        Called once per decoded frame image.
    """
    root = Path(root)
    if not root.is_dir():
        return [Problem(root, "dataset folder not found")]
    problems: list[Problem] = []
    config = None
    try:
        config = read_probe_toml(root / "probe.toml")
    except DatasetError as exc:
        problems.append(Problem(exc.path or root, exc.problem))
    problems.extend(_check_frames(root, config, progress))
    frames_dir = root / "frames"
    lasers = frame_files(frames_dir)[0]["laser"] if frames_dir.is_dir() else {}
    # pairs as numbered (a gap in the numbering is reported with the frames)
    n_pairs = max(lasers) + 1 if lasers else None
    problems.extend(check_odometry_and_imu(
        root, n_pairs, pairs_held("frames/", n_pairs) if n_pairs else ""))
    if config is not None:
        try:
            problems.extend(Problem(mask_path(root, config), note, "warning")
                            for note in mask_notes(read_mask(root, config), config))
        except DatasetError as exc:
            problems.append(Problem(exc.path or root, exc.problem))
    problems.extend(_check_truth(root))
    problems.extend(_check_survey(root))
    return problems


def _check_survey(root: Path) -> list[Problem]:
    """The optional survey.toml, read as the standards stage reads it."""
    from pipestitch.io.survey_toml import SURVEY_FILE, read_survey_toml  # no cycle at import

    try:
        read_survey_toml(root)
    except DatasetError as exc:
        return [Problem(exc.path or root / SURVEY_FILE, exc.problem)]
    return []
