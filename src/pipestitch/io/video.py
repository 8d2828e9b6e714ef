"""Video input (PyAV): alternating laser/LED frames, paired by their content.

A probe that records video interleaves laser frames (laser on, LEDs off: dark with a
bright thin ring) and LED frames (the lit wall). :class:`VideoReader` opens a video,
indexes it once (timestamp and one brightness statistic per frame), tells laser frames
from LED frames by that statistic, pairs them, re-synchronises where a frame was
dropped, and then gives random access to any frame with a small bounded cache, so
memory does not grow with the length of the video. :func:`write_video` turns frames
into a lossless video (tests, benchmarks).

A pair's number is its place in the recording, as the probe's odometer and IMU count
it: frames missing from the video (dropped when it was written, or whose packet the
decoder refuses) leave their pairs' numbers unused rather than renumbering the pairs
after them. Where frames are missing is read from the alternation (two frames of a
kind in a row) and the timestamps (a gap of whole pairs); every missing frame is
reported.

It does not know about probe.toml or datasets: ``io.dataset.open_dataset(root,
video=...)`` wraps a reader in the Dataset interface.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io import images

if TYPE_CHECKING:
    import av

__all__ = [
    "FrameIndex",
    "VideoPairs",
    "VideoReader",
    "classify_laser_frames",
    "frame_brightness",
    "pair_frames",
    "write_video",
]

# Decoded frames kept for random access: a pair (2) read by each of a few worker
# threads, slightly out of order. Small and fixed, so memory is bounded.
CACHE_FRAMES = 8
# A frame this many frames ahead of the decoder is reached by decoding forward;
# further (or behind), by seeking to the preceding keyframe.
FORWARD_DECODE_LIMIT = 24
# The frame number of a pair's frame that is not in the video (VideoPairs).
MISSING = -1


@dataclass(frozen=True)
class FrameIndex:
    """Per-frame facts gathered in one pass over the video."""

    pts: np.ndarray  # (F,) int64, presentation timestamps in the stream's time base
    time_s: np.ndarray  # (F,) float, pts * time_base
    brightness: np.ndarray  # (F,) float, see frame_brightness
    width: int
    height: int
    # One line per frame the decoder refused (its packet is damaged): not in the index;
    # and one when the frames end well before the file's declared length (cut short).
    undecodable: tuple[str, ...] = ()
    # Time of the recording's first frame, decodable or not (a refused packet's
    # timestamp can be earlier than the first decoded frame's); NaN when unknown.
    start_s: float = float("nan")
    refused_before: int = 0   # refused packets timestamped before the first decoded frame


@dataclass(frozen=True)
class VideoPairs:
    """Frame pairs numbered by their place in the recording: ``laser[i]`` and ``led[i]``
    are the frame numbers of pair i, ``MISSING`` (-1) where that frame is not in the video
    (a pair may lack one frame, or both when whole pairs were dropped)."""

    laser: np.ndarray  # (P,) int, -1 where the pair's laser frame is missing
    led: np.ndarray  # (P,) int, -1 where the pair's LED frame is missing
    messages: tuple[str, ...]  # one line per missing frame or gap, for the user
    laser_first: bool


def frame_brightness(image: np.ndarray) -> float:
    """Upper-quartile brightness of a frame as a fraction of its dtype's range.

    A laser frame is dark but for a thin ring (a few % of the pixels), so its upper
    quartile is near the noise floor; an LED frame's is the lit wall. A quantile
    rather than the mean, so that the ring's brightness (and glints) barely move it;
    the upper quartile rather than the median because the mirror and the outside of
    the image circle are dark in both kinds of frame.
    """
    sample = image[::4, ::4]  # every 16th pixel: plenty for a quantile, 16x cheaper
    grey = sample if sample.ndim == 2 else sample.mean(axis=2)
    scale = float(np.iinfo(image.dtype).max) if image.dtype.kind in "ui" else 1.0
    return float(np.percentile(grey, 75)) / scale


def classify_laser_frames(brightness: np.ndarray) -> np.ndarray:
    """True for laser frames: the darker of two brightness classes (Otsu, log scale).

    Otsu's split of log-brightness (between-class variance maximised) needs no tuned
    threshold: it separates the two
    populations wherever they lie (8- or 16-bit, exposure), on the ratio scale where
    "an order of magnitude darker" is what distinguishes them.

    Raises
    ------
    ValueError
        If fewer than two frames are given or all frames are equally bright.
    """
    # + 1/255: one 8-bit grey level, so that sensor noise near 0 does not spread dark
    # frames over orders of magnitude.
    values = np.log(np.asarray(brightness, dtype=float) + 1 / 255)
    if values.size < 2 or np.ptp(values) == 0:
        raise ValueError("cannot tell laser from LED frames: all frames equally bright")
    return values <= _otsu_exact(values)


def _otsu_exact(values: np.ndarray) -> float:
    """Otsu's threshold over the sorted values themselves, midway between two of them.

    Hand-written (a cumulative sum) because skimage's ``threshold_otsu`` works on a
    256-bin histogram and returns a bin centre, which can cut a tight cluster of
    frames in two (seen in testing); a few thousand values need no histogram.
    """
    v = np.sort(values)
    n = v.size
    k = np.arange(1, n)  # split after the k smallest values
    csum = np.cumsum(v)[:-1]
    mean_low, mean_high = csum / k, (v.sum() - csum) / (n - k)
    between = k * (n - k) * (mean_high - mean_low) ** 2
    between[v[1:] == v[:-1]] = -1.0  # never split equal values
    best = int(np.argmax(between))
    return float((v[best] + v[best + 1]) / 2)


def _frame_period(is_laser: np.ndarray, time_s: np.ndarray) -> float | None:
    """The frame period: half the median time from a frame to the next of its kind across
    one frame of the other kind (a pair period), so uneven spacing within a pair (the
    probe's few tens of ms between its two frames) does not matter. None without such
    frames or usable timestamps."""
    k = np.flatnonzero((is_laser[2:] == is_laser[:-2]) & (is_laser[1:-1] != is_laser[2:]))
    spans = time_s[k + 2] - time_s[k]
    spans = spans[np.isfinite(spans)]
    period = float(np.median(spans)) / 2 if spans.size else 0.0
    return period if period > 0 else None


def _missing_between(is_laser: np.ndarray, time_s: np.ndarray | None, period: float | None
                     ) -> tuple[np.ndarray, list[tuple[int, str]]]:
    """How many frames are missing between each frame and the next, and notes.

    Two frames of a kind in a row miss an odd number between them, alternating frames
    an even number; of those counts, the one nearest what the timestamps say (the step
    over the frame period, less one; ties to fewer, none without timestamps). A jump
    longer than the whole video is a timestamp discontinuity, not lost frames.
    ``period``: the frame period (:func:`_frame_period`); None counts by alternation only.
    """
    same = (is_laser[1:] == is_laser[:-1]).astype(int)
    if period is None:
        return same, []
    steps = np.diff(time_s)
    estimate = steps / period - 1
    jump = ~np.isfinite(estimate) | (estimate > is_laser.size)
    estimate[jump] = 0.0
    # the nearest count of the right parity: 2 * (nearest whole number to half the excess)
    extra = 2 * np.maximum(0, np.ceil((estimate - same) / 2 - 0.5)).astype(int)
    notes = [(int(k), f"frames {k}-{k + 1}: timestamp jump of {steps[k]:.4g} s, longer than "
                      "the video: not counted as dropped frames")
             for k in np.flatnonzero(jump & np.isfinite(steps))]
    return same + extra, notes


def _leading(time_s: np.ndarray | None, start_s: float | None, period: float | None,
             most: int) -> int:
    """Frames of the recording before the first decoded one (refused by the decoder):
    the time from the recording's start to that frame over the frame period, at most
    ``most`` (the packets refused before it: a stray timestamp adds no frames)."""
    if time_s is None or start_s is None or period is None or not np.isfinite(start_s):
        return 0
    return min(most, max(0, int(round((time_s[0] - start_s) / period))))


def pair_frames(is_laser: np.ndarray, time_s: np.ndarray | None = None,
                start_s: float | None = None, refused_before: int = 0) -> VideoPairs:
    """Pair alternating laser/LED frames, numbering each pair by its place in the recording.

    A frame's place is its index in the video plus the frames missing before it (see
    :func:`_missing_between`: two frames of a kind in a row, timestamp gaps; before the
    first decoded frame, those from ``start_s``, the recording's first timestamp, on, at
    most the ``refused_before`` packets the decoder refused there), so the pairs after a
    dropped frame keep their numbers. The order within a pair (laser
    first or LED first) is the one that completes more pairs (ties: laser first). A pair
    lacking a frame has ``MISSING`` there: without its LED frame it still gives a pose
    (no strip); without its laser frame, or with neither (whole pairs dropped), it gives
    none, but keeps its number. Every such pair is reported in ``messages``, one line
    naming the frame or the gap.
    """
    is_laser = np.asarray(is_laser, dtype=bool)
    if is_laser.size == 0:
        return VideoPairs(np.zeros(0, dtype=int), np.zeros(0, dtype=int), (), True)
    time_s = None if time_s is None else np.asarray(time_s, dtype=float)
    period = None if time_s is None or time_s.size < 3 else _frame_period(is_laser, time_s)
    missing, notes = _missing_between(is_laser, time_s, period)
    lead = _leading(time_s, start_s, period, refused_before)
    place = lead + np.concatenate([[0], np.cumsum(1 + missing)])
    laser_parity = int(place[0] + (0 if is_laser[0] else 1)) % 2  # every laser frame's
    best = None
    for laser_first in (True, False):   # only more complete pairs beat laser first
        pair = (place + (laser_parity + (0 if laser_first else 1)) % 2) // 2
        complete = np.intersect1d(pair[is_laser], pair[~is_laser]).size
        if best is None or complete > best[0]:
            best = (complete, laser_first, pair)
    _, laser_first, pair = best
    laser = np.full(int(pair[-1]) + 1, MISSING, dtype=int)
    led = laser.copy()
    laser[pair[is_laser]] = np.flatnonzero(is_laser)
    led[pair[~is_laser]] = np.flatnonzero(~is_laser)
    notes += _pair_notes(laser, led, missing, time_s)
    return VideoPairs(laser, led, tuple(m for _, m in sorted(notes, key=lambda n: n[0])),
                      laser_first)


def _pair_notes(laser: np.ndarray, led: np.ndarray, missing: np.ndarray,
                time_s: np.ndarray | None) -> list[tuple[int, str]]:
    """(frame, line) for every pair lacking a frame: the lone frame named, or the gap
    where whole pairs are missing."""
    def at(k: int) -> str:
        return f"frame {k}" if time_s is None else f"frame {k} ({time_s[k]:.3f} s)"

    notes = []
    p, n_pairs = 0, laser.size
    while p < n_pairs:
        if laser[p] >= 0 and led[p] < 0:
            notes.append((int(laser[p]), f"{at(laser[p])}: laser frame without its LED frame "
                                         f"(dropped or undecodable); pair {p} has no LED frame"))
        elif led[p] >= 0 and laser[p] < 0:
            notes.append((int(led[p]), f"{at(led[p])}: LED frame without its laser frame "
                                       f"(dropped or undecodable); pair {p} has no laser frame"))
        elif laser[p] < 0 and led[p] < 0:
            last = p
            while last + 1 < n_pairs and laser[last + 1] < 0 and led[last + 1] < 0:
                last += 1
            pairs = f"pair {p} has" if last == p else f"pairs {p}-{last} have"
            if p == 0:   # the recording's first frames were refused by the decoder
                notes.append((0, f"the recording's first frames before frame 0 cannot be "
                                 f"decoded; {pairs} no frame"))
            else:
                k = int(max(laser[p - 1], led[p - 1]))
                step = ("" if time_s is None
                        else f"timestamp gap of {time_s[k + 1] - time_s[k]:.4g} s, ")
                notes.append((k, f"frames {k}-{k + 1}: {step}{missing[k]} frame(s) dropped; "
                                 f"{pairs} no frame"))
            p = last
        p += 1
    return notes


def _ndarray_format(pix_fmt: str) -> str:
    """The numpy layout a stream decodes to: grey stays grey, colour becomes BGR."""
    if pix_fmt in ("gray", "gray8"):
        return "gray"
    if pix_fmt.startswith("gray"):
        return "gray16le"
    deep = any(tag in pix_fmt for tag in ("10", "12", "14", "16", "48", "64"))
    return "bgr48le" if deep else "bgr24"


class VideoReader:
    """Random access to the frames of a video with a small, bounded cache.

    Opening indexes the video (decodes every frame once for its timestamp and
    brightness); :meth:`frame` then decodes forward from the current position or
    seeks to the preceding keyframe. Thread-safe (one decoder behind a lock).
    A frame whose packet the decoder refuses is left out of the index (frame numbers
    count the frames decoded) and reported: a warning when the video is opened, and
    ``index.undecodable`` (which also says when the frames end well before the length
    the file declares for them: a file cut short).

    Parameters
    ----------
    path : Path
        Any video PyAV reads; the first video stream is used.
    progress : callable, optional
        Called once per frame during indexing.

    Raises
    ------
    DatasetError
        Naming the file when it is missing, not a video or has no video stream.
    """

    def __init__(self, path: str | Path, *, progress: Callable[[], None] | None = None,
                 ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DatasetError(self.path, "video file not found")
        self._lock = threading.Lock()
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._container = self._open()
        try:
            self._stream = self._container.streams.video[0]
            pixel_format = self._stream.codec_context.format
            if pixel_format is None:
                raise DatasetError(self.path, "the video stream has no pixel format")
            self._format = _ndarray_format(pixel_format.name)
            self.index = self._build_index(progress)
            self._pts_to_frame = {int(p): k for k, p in enumerate(self.index.pts)}
            self._decoder: Iterator[av.VideoFrame] | None = None
            self._next = 0  # frame number the decoder yields next
            self._seek_to(0)
        except BaseException:
            self._container.close()   # a failed open leaves no decoder behind
            raise

    def _open(self) -> av.container.InputContainer:
        import av  # PyAV on first use (~0.1 s): runs of image files never load it

        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, OSError) as exc:
            raise DatasetError(self.path, f"cannot open as a video: {exc}") from exc
        if not container.streams.video:
            container.close()
            raise DatasetError(self.path, "no video stream in the file")
        stream = container.streams.video[0]
        width, height = int(stream.width or 0), int(stream.height or 0)
        if width * height > images.MAX_PIXELS:   # measured before a frame is decoded
            container.close()
            raise DatasetError(self.path, f"the video declares {width}x{height} pixels a frame, "
                                          f"more than {images.MAX_PIXELS:,}; not decoded")
        # Slice threads only: frame threading would decode several frames ahead after
        # every seek (measured: no faster here, and random access is slower).
        container.streams.video[0].thread_type = "SLICE"
        return container

    def _decode_all(self, refused: list[tuple[int | None, str]] | None = None
                    ) -> Iterator[av.VideoFrame]:
        """The frames from the current position. A packet the decoder refuses (a damaged
        frame) is skipped, its (pts, reason) added to ``refused``: one bad frame does not
        make the video unreadable."""
        import av

        try:
            for packet in self._container.demux(self._stream):
                try:
                    frames = packet.decode()
                except av.FFmpegError as exc:
                    if refused is not None:
                        refused.append((packet.pts, exc.strerror or str(exc)))
                    continue
                yield from frames
        except av.FFmpegError as exc:
            raise DatasetError(self.path, f"cannot read the video: {exc}") from exc

    def _build_index(self, progress: Callable[[], None] | None) -> FrameIndex:
        pts, bright = [], []
        refused: list[tuple[int | None, str]] = []
        size = None
        for frame in self._decode_all(refused):
            image = frame.to_ndarray(format=self._format)
            size = size or (frame.width, frame.height)
            pts.append(frame.pts if frame.pts is not None else len(pts))
            bright.append(frame_brightness(image))
            if progress is not None:
                progress()
        if not pts:
            why = f": {refused[0][1]}" if refused else ""
            raise DatasetError(self.path, f"the video has no frame that can be decoded{why}")
        order = np.argsort(pts, kind="stable")
        pts_arr = np.asarray(pts, dtype=np.int64)[order]
        base = float(self._stream.time_base or Fraction(1, 1))
        undecodable = tuple(_undecodable_line(pts_arr, base, p, reason) for p, reason in refused)
        cut = _cut_short_line(pts_arr * base, *self._declared_span_s(base),
                              sum(1 for p, _ in refused if p is not None and p > pts_arr[-1]))
        undecodable += (cut,) if cut else ()
        for line in undecodable:
            logging.getLogger(__name__).warning("%s: %s", self.path, line)
        before = [p for p, _ in refused if p is not None and p < pts_arr[0]]
        return FrameIndex(pts_arr, pts_arr * base, np.asarray(bright)[order],
                          size[0], size[1], undecodable, min([int(pts_arr[0]), *before]) * base,
                          len(before))

    def _declared_span_s(self, time_base: float) -> tuple[float | None, float | None]:
        """(start, duration) in seconds the file declares for the video stream: the
        stream's own where it has them, else the container's when the video is its only
        stream (a container's length spans every stream: an audio track may outlast the
        video); (None, None) when unknown."""
        stream = self._stream
        if stream.duration is not None:
            return (stream.start_time or 0) * time_base, stream.duration * time_base
        if len(self._container.streams) == 1 and self._container.duration is not None:
            return (self._container.start_time or 0) / 1e6, self._container.duration / 1e6
        return None, None

    @property
    def n_frames(self) -> int:
        """Number of frames in the video."""
        return len(self.index.pts)

    def _seek_to(self, k: int) -> None:
        import av

        try:
            self._container.seek(int(self.index.pts[k]), stream=self._stream, backward=True,
                                 any_frame=False)
        except (av.FFmpegError, ValueError) as exc:
            raise DatasetError(self.path, f"cannot seek to frame {k}: {exc}") from exc
        self._decoder = self._decode_all()
        self._next = -1  # unknown until the first frame after the seek is decoded

    def _decode_next(self) -> tuple[int, np.ndarray]:
        import av

        try:
            frame = next(self._decoder)
        except StopIteration:
            raise DatasetError(self.path, "video ended before the requested frame") from None
        k = self._pts_to_frame.get(frame.pts, self._next) if frame.pts is not None else self._next
        self._next = k + 1
        try:
            return k, frame.to_ndarray(format=self._format)
        except (av.FFmpegError, ValueError) as exc:
            raise DatasetError(self.path, f"cannot convert frame {k}: {exc}") from exc

    def frame(self, k: int) -> np.ndarray:
        """Frame ``k`` (0-based, in presentation order): grey, or colour as BGR.

        Raises
        ------
        DatasetError
            If ``k`` is out of range or the frame cannot be decoded; ``MISSING`` (a pair's
            frame that is not in the video, :class:`VideoPairs`) is refused saying so.
        """
        if k == MISSING:
            raise DatasetError(self.path, "frame missing from the video (dropped or "
                                          "undecodable: reported when the video was opened)")
        if not 0 <= k < self.n_frames:
            raise DatasetError(self.path, f"frame {k} out of range (0..{self.n_frames - 1})")
        with self._lock:
            if k in self._cache:
                self._cache.move_to_end(k)
                # A copy: callers may work in place, the cache must stay as decoded.
                return self._cache[k].copy()
            if not (0 <= self._next <= k < self._next + FORWARD_DECODE_LIMIT):
                self._seek_to(k)
            while True:
                got, image = self._decode_next()
                self._remember(got, image)
                if got >= k:
                    break
            if k not in self._cache:
                raise DatasetError(self.path, f"frame {k} could not be decoded")
            return self._cache[k].copy()

    def _remember(self, k: int, image: np.ndarray) -> None:
        self._cache[k] = image
        self._cache.move_to_end(k)
        while len(self._cache) > CACHE_FRAMES:
            self._cache.popitem(last=False)

    def close(self) -> None:
        """Release the decoder."""
        with self._lock:
            self._container.close()
            self._cache.clear()


def _undecodable_line(pts: np.ndarray, time_base: float, refused_pts: int | None,
                      reason: str) -> str:
    """The warning for a frame the decoder refused, placed among the decoded frames."""
    if refused_pts is None:
        return f"a frame without a timestamp cannot be decoded ({reason}); skipped"
    after = int(np.searchsorted(pts, refused_pts))   # decoded frames before it
    where = ("before frame 0" if after == 0 else f"after frame {after - 1}" if after == pts.size
             else f"between frames {after - 1} and {after}")
    return (f"the frame at {refused_pts * time_base:.3f} s ({where}) cannot be decoded "
            f"({reason}); skipped")


CUT_SHORT_FRAMES = 2   # frames missing at the end before a video is said to be cut short


def _cut_short_line(time_s: np.ndarray, start_s: float | None, duration_s: float | None,
                    refused_after: int = 0) -> str | None:
    """The warning for a video whose frames end well before the length the file
    declares for them (a file cut short: a copy or a recording that stopped); None
    otherwise.

    ``start_s`` and ``duration_s``: the video stream's declared span (seconds; None where
    the file declares none, :meth:`VideoReader._declared_span_s`). The frames' period is
    their median step; ``refused_after`` frames past the last decoded one were reported
    as undecodable already and are not counted again; frames missing at the end are only
    counted from ``CUT_SHORT_FRAMES`` on, so that a rounded duration says nothing.
    """
    if duration_s is None or time_s.size < 2:
        return None
    period = float(np.median(np.diff(time_s)))
    if not period > 0:
        return None
    declared_end = (start_s or 0.0) + duration_s
    decoded_end = float(time_s[-1]) + period
    missing = int(round((declared_end - decoded_end) / period)) - refused_after
    if missing < CUT_SHORT_FRAMES:
        return None
    return (f"the file declares {declared_end:.3f} s but its frames end at {decoded_end:.3f} s: "
            f"about {missing} frame(s) missing at the end (the file cut short?)")


# Lossless codecs of the PyAV wheel, with a container that holds them. FFVHuff
# (HuffYUV) decodes ~4x faster than FFV1 (23 vs 110 ms for a 1224 x 1024 grey frame,
# measured on this machine under load; PNG: 34 ms) for ~30 % larger files, so it is
# the default; FFV1 in Matroska is the archival choice.
CODEC_CONTAINERS = {"ffvhuff": "avi", "ffv1": "matroska"}


def _encoder_format(image: np.ndarray, codec: str) -> tuple[str, str]:
    """(input layout, stream pix_fmt) for a frame: both lossless for every layout."""
    grey, deep = image.ndim == 2, image.dtype == np.uint16
    if grey:
        return ("gray16le", "gray16le") if deep else ("gray", "gray")
    if deep:
        return "bgr48le", "gbrp16le"
    return "bgr24", ("bgr0" if codec == "ffv1" else "gbrp")


def write_video(path: str | Path, frames: Iterable[np.ndarray], *, fps: float = 30.0,
                codec: str = "ffvhuff", frame_numbers: Iterable[int] | None = None) -> Path:
    """Write frames (grey or BGR, 8- or 16-bit) to a lossless video, atomically.

    FFVHuff (AVI) and FFV1 (Matroska) are lossless for 8/16-bit grey and colour, so a
    run read from the video sees exactly the frames of the dataset. (The wheel's
    libx264 stores grey in limited range: not lossless without extra range handling.)

    Parameters
    ----------
    path : Path
        Output file (``.avi`` for ffvhuff, ``.mkv`` for ffv1).
    frames : iterable of ndarray
        All of one shape and dtype; consumed lazily (one frame in memory at a time).
    fps : float
        Nominal frame rate (the time base is 1/fps).
    codec : {"ffvhuff", "ffv1"}
        Both intra-only: every frame is a keyframe, so seeks are exact.
    frame_numbers : iterable of int, optional
        Timestamp of each frame in frame periods (default 0, 1, 2, ...): gaps
        simulate dropped frames.
    """
    import av

    from pipestitch.io.atomic import atomic_path

    if codec not in CODEC_CONTAINERS:
        raise ValueError(f"codec: expected one of {sorted(CODEC_CONTAINERS)}, got {codec!r}")
    path = Path(path)
    numbers = iter(frame_numbers) if frame_numbers is not None else None
    rate = Fraction(fps).limit_denominator(1001)
    with atomic_path(path) as tmp, av.open(str(tmp), mode="w",
                                           format=CODEC_CONTAINERS[codec]) as out:
        stream = None
        for k, image in enumerate(frames):
            if stream is None:
                layout, pix_fmt = _encoder_format(image, codec)
                stream = out.add_stream(codec, rate=rate)
                stream.width, stream.height = image.shape[1], image.shape[0]
                stream.pix_fmt = pix_fmt
                stream.codec_context.time_base = 1 / rate
                stream.options = {"g": "1", "slices": "4"} if codec == "ffv1" else {}
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format=layout)
            frame.pts = next(numbers) if numbers is not None else k
            frame.time_base = 1 / rate
            out.mux(stream.encode(frame))
        if stream is not None:
            out.mux(stream.encode(None))
    return path
