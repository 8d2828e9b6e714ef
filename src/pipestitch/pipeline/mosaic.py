"""The mosaic stages: unwrap every LED frame, register the run, stitch the canvas.

Two passes over the LED frames, each frame unwrapped straight from its pixels:

1. every frame is unwrapped over its own axial window (at the mosaic's scale) and
   linked to the next two frames by phase correlation; the run's positions (z, roll)
   are solved globally with the odometer; the vignetting profile is collected;
2. every placed frame is unwrapped again, this time onto the canvas nodes it covers
   (sub-pixel, so the image is resampled once), shaded, gain-matched and blended.

Re-reading a frame costs one decode; holding the strips instead would make memory
grow with the run. Frames that cannot be read, have no pose, or are not connected to
the run by registration or the odometer are reported and skipped.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pipestitch.camera import CameraModel
from pipestitch.errors import DatasetError
from pipestitch.geometry import PipeSection, Pose
from pipestitch.io.dataset import Dataset
from pipestitch.mosaic import Canvas, canvas_grid, frame_grid, vignetting_profile
from pipestitch.occluder import occluder_mask
from pipestitch.pipeline.pose import ordered_map
from pipestitch.pipeline.progress import StageTimer, track
from pipestitch.register import Link, Positions, measure_shift, registration_image, solve_positions
from pipestitch.unwrap import (
    Strip,
    StripGrid,
    UnwrapMaps,
    default_mm_per_px,
    polar_unwrap_maps,
    strip_window_mm,
    to_grey,
    unwrap_maps,
    unwrap_with_quality,
)

__all__ = ["UNWRAP_MODES", "FrameView", "MosaicResult", "MosaicSettings", "build_mosaic"]

UNWRAP_MODES = ("ours", "centred", "polar")
LINK_SPAN = 2          # each frame is registered to this many following frames


@dataclass(frozen=True)
class MosaicSettings:
    """How to unwrap and stitch.

    Attributes
    ----------
    mm_per_px : float, optional
        Output scale on the wall (both axes); default from the camera and the pipe
        (:func:`pipestitch.unwrap.default_mm_per_px`).
    mode : {"ours", "centred", "polar"}
        ``ours`` unwraps with each frame's pose; ``centred`` forces the pose to a
        centred probe (no centralisation); ``polar`` is the prior-art polar unwrap
        about the image centre. The last two exist for the benchmark.
    workers : int
        Threads (frames stay in order).
    step : int
        Exact projection every ``step`` grid nodes, interpolated between.
    min_resolution : float
        Nodes drawing on fewer source pixels per output pixel are masked.
    reference_frames : int
        LED frames sampled along the run to find the occluders.
    """

    mm_per_px: float | None = None
    mode: str = "ours"
    workers: int = 2
    step: int = 4
    min_resolution: float = 0.5
    reference_frames: int = 11

    def __post_init__(self) -> None:
        if self.mode not in UNWRAP_MODES:
            raise ValueError(f"mode: expected one of {UNWRAP_MODES}, got {self.mode!r}")
        if self.mm_per_px is not None and not (np.isfinite(self.mm_per_px)
                                               and self.mm_per_px > 0):
            raise ValueError(f"mm_per_px: expected a positive number, got {self.mm_per_px}")


@dataclass(frozen=True)
class FrameView:
    """The pose and pipe section a frame is unwrapped with.

    ``alternative`` is the mirror hypothesis of a frame the pose step left ambiguous:
    registration then keeps whichever agrees better with the previous frames.
    """

    pose: Pose
    section: PipeSection
    alternative: FrameView | None = None


@dataclass
class MosaicResult:
    """Output of :func:`build_mosaic`.

    ``image`` is float (NaN where no data) on ``grid``; ``skipped`` maps frame -> why;
    ``switched`` says, for each frame the pose step left ambiguous, whether registration
    chose its mirror hypothesis instead.
    """

    grid: StripGrid
    image: np.ndarray
    weights: np.ndarray
    positions: Positions
    links: list[Link]
    radius_mm: float
    window_mm: tuple[float, float]
    placed: list[int]
    skipped: dict[int, str] = field(default_factory=dict)
    gains: dict[int, float] = field(default_factory=dict)
    switched: dict[int, bool] = field(default_factory=dict)


@dataclass(frozen=True)
class _Unwrapper:
    camera: CameraModel
    settings: MosaicSettings
    radius_mm: float
    occluded: np.ndarray

    def maps(self, view: FrameView, grid: StripGrid) -> UnwrapMaps:
        if self.settings.mode == "polar":
            return polar_unwrap_maps(self.camera, self.radius_mm, grid)
        return unwrap_maps(self.camera, view.pose, view.section, grid, step=self.settings.step,
                           with_quality=True)

    def strip(self, grey: np.ndarray, view: FrameView, grid: StripGrid) -> Strip:
        return unwrap_with_quality(grey, self.maps(view, grid),
                                   min_resolution=self.settings.min_resolution,
                                   occluded=self.occluded)


def _read_grey(dataset: Dataset, index: int, timer: StageTimer) -> np.ndarray:
    with timer("decode"):
        return to_grey(dataset.read_led(index))


def _occluders(dataset: Dataset, frames: Sequence[int], count: int,
               timer: StageTimer) -> np.ndarray:
    """Occluder mask from up to ``count`` readable LED frames spread over ``frames``."""
    picks = sorted({frames[k] for k in np.linspace(0, len(frames) - 1, count).round().astype(int)})
    greys = []
    for i in picks:
        try:
            greys.append(_read_grey(dataset, i, timer))
        except DatasetError:
            continue  # reported when the frame itself is processed
    if not greys:
        raise DatasetError(dataset.root / "frames", "no readable LED frame")
    with timer("occluders"):
        return occluder_mask(greys)


def _column_levels(strip: Strip) -> np.ndarray:
    """Median over theta of strip / shading per column (NaN where a column has no data)."""
    ratio = np.where(strip.weight > 0, strip.values / np.maximum(strip.shading, 1e-6), np.nan)
    out = np.full(ratio.shape[1], np.nan)
    enough = np.sum(np.isfinite(ratio), axis=0) > 0.1 * ratio.shape[0]
    if enough.any():
        out[enough] = np.nanmedian(ratio[:, enough], axis=0)
    return out


@dataclass(frozen=True)
class _Registered:
    """Pass-1 result of one frame: registration image and levels per candidate view."""

    index: int
    images: list[np.ndarray]
    levels: list[np.ndarray]
    error: str = ""


def _links_to(recent: Sequence[tuple[int, np.ndarray]], image: np.ndarray, grid: StripGrid,
              i: int) -> list[Link]:
    found = (measure_shift(previous, image, grid, j, i) for j, previous in recent)
    return [link for link in found if link is not None]


def _register(dataset: Dataset, views: dict[int, FrameView], unwrapper: _Unwrapper,
              own: StripGrid, timer: StageTimer, show_progress: bool,
              skipped: dict[int, str]) -> tuple[list[Link], list[np.ndarray], list[int],
                                                 dict[int, bool]]:
    """Pass 1: own-window strips, links to the next frames, vignetting levels.

    For a frame left ambiguous by the pose step both hypotheses are unwrapped and the
    one whose strip correlates better with the previous frames is kept (``views`` is
    updated; the returned dict says which frames switched to their mirror).
    """
    def work(i: int) -> _Registered:
        try:
            grey = _read_grey(dataset, i, timer)
        except DatasetError as exc:
            return _Registered(i, [], [], f"{exc.path.name}: {exc.problem}")
        candidates = [views[i]] + ([views[i].alternative] if views[i].alternative else [])
        images, levels = [], []
        for view in candidates:
            with timer("unwrap"):
                strip = unwrapper.strip(grey, view, own)
            with timer("register"):
                images.append(registration_image(strip))
                levels.append(_column_levels(strip))
        return _Registered(i, images, levels)

    links: list[Link] = []
    levels: list[np.ndarray] = []
    done: list[int] = []
    switched: dict[int, bool] = {}
    recent: deque[tuple[int, np.ndarray]] = deque(maxlen=LINK_SPAN)
    order = sorted(views)
    for reg in track(ordered_map(work, order, unwrapper.settings.workers), "register",
                     total=len(order), enabled=show_progress):
        if not reg.images:
            skipped[reg.index] = reg.error
            continue
        with timer("register"):
            found = [_links_to(recent, image, own, reg.index) for image in reg.images]
        best = 0
        if len(found) > 1 and any(found):
            scores = [sum(link.response for link in f) for f in found]
            best = int(np.argmax(scores))
            switched[reg.index] = best == 1
            if best == 1:
                views[reg.index] = views[reg.index].alternative  # type: ignore[assignment]
        links += found[best]
        recent.append((reg.index, reg.images[best]))
        levels.append(reg.levels[best])
        done.append(reg.index)
    return links, levels, done, switched


def _stitch(dataset: Dataset, views: Mapping[int, FrameView], unwrapper: _Unwrapper,
            positions: Positions, placed: list[int], canvas: Canvas, window: tuple[float, float],
            profile: Callable[[np.ndarray], np.ndarray], timer: StageTimer,
            show_progress: bool, skipped: dict[int, str]) -> dict[int, float]:
    """Pass 2: every placed frame onto the canvas nodes it covers."""
    def work(i: int) -> tuple[int, Strip | None, int, StripGrid | None, str]:
        grid, col = frame_grid(canvas.grid, positions.z_mm[i], positions.roll_deg[i], window)
        try:
            grey = _read_grey(dataset, i, timer)
        except DatasetError as exc:  # readable in pass 1: changed on disk since
            return i, None, col, None, f"{exc.path.name}: {exc.problem}"
        with timer("unwrap"):
            return i, unwrapper.strip(grey, views[i], grid), col, grid, ""

    gains = {}
    for i, strip, col, grid, error in track(ordered_map(work, placed, unwrapper.settings.workers),
                                            "stitch", total=len(placed), enabled=show_progress):
        if strip is None or grid is None:
            skipped[i] = error
            continue
        z_local = grid.z0_mm + np.arange(grid.n_cols) * grid.mm_per_px
        with timer("blend"):
            gains[i] = canvas.add(strip, col, profile(z_local))
    return gains


def _views(poses: Mapping[int, FrameView], mode: str,
           nominal_radius_mm: float) -> dict[int, FrameView]:
    if mode == "ours":
        return dict(poses)
    return {i: FrameView(Pose(), PipeSection(nominal_radius_mm)) for i in poses}


def build_mosaic(dataset: Dataset, poses: Mapping[int, FrameView],
                 settings: MosaicSettings, *, timer: StageTimer | None = None,
                 show_progress: bool = True) -> MosaicResult:
    """Unwrap, register and stitch the frames that have a pose.

    Parameters
    ----------
    dataset : Dataset
        The run (LED frames, camera, odometer).
    poses : mapping
        Frame index -> view (chosen pose and fitted section, the mirror for ambiguous
        frames) for the frames to use.
    settings : MosaicSettings
        Scale, unwrap mode, threads.
    """
    timer = timer or StageTimer()
    if not dataset.has_led:
        raise DatasetError(dataset.root / "frames", "no LED frames: nothing to stitch")
    camera = dataset.config.camera_model()
    nominal = dataset.config.pipe.inner_diameter_mm / 2
    radii = [v.section.mean_radius_mm for v in poses.values()]
    radius = float(np.median(radii)) if radii and settings.mode == "ours" else nominal
    mm = settings.mm_per_px or default_mm_per_px(camera, radius)
    window = strip_window_mm(camera, radius, mm, min_resolution=settings.min_resolution)
    own = StripGrid.window(radius, mm, *window)
    skipped: dict[int, str] = {i: "no LED frame" for i in dataset.led_missing() if i in poses}
    usable = {i: p for i, p in poses.items() if i not in skipped}
    if not usable:
        raise DatasetError(dataset.root / "frames", "no frame has both a pose and an LED frame")
    occluded = _occluders(dataset, sorted(usable), settings.reference_frames, timer)
    unwrapper = _Unwrapper(camera, settings, radius, occluded)
    views = _views(usable, settings.mode, nominal)
    links, levels, done, switched = _register(dataset, views, unwrapper, own, timer,
                                              show_progress, skipped)
    with timer("register"):
        positions = solve_positions(dataset.n_pairs, links, odometry_mm=dataset.odometry_mm,
                                    placed=done)
    placed = [i for i in done if np.isfinite(positions.z_mm[i])]
    for i in done:
        if i not in placed:
            skipped[i] = "not registered to the run (no common texture, no odometer)"
    if not placed:
        raise DatasetError(dataset.root / "frames", "no frame could be placed in the mosaic")
    prof = vignetting_profile(levels)
    z_own = own.z0_mm + np.arange(own.n_cols) * mm

    def profile(z_local: np.ndarray) -> np.ndarray:
        return np.interp(z_local, z_own, prof) if prof.size else np.ones_like(z_local)

    canvas = Canvas(canvas_grid(positions.z_mm, window, own))
    gains = _stitch(dataset, views, unwrapper, positions, placed, canvas, window, profile,
                    timer, show_progress, skipped)
    image, weights = canvas.image()
    return MosaicResult(canvas.grid, image, weights, positions, links, radius, window,
                        [i for i in placed if i in gains], skipped, gains, switched)
