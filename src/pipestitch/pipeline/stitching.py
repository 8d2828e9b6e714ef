"""The mosaic stages: unwrap every LED frame, register the run, stitch the canvas.

Two passes over the LED frames, each frame unwrapped straight from its pixels:

1. every frame is unwrapped over its own axial window (at the mosaic's scale) and
   linked to the next two frames by phase correlation; the run's positions (z, roll)
   are solved globally with the odometer (or taken as known, when the caller gives
   them); the lens' fall-off is measured (flat_field);
2. every placed frame is unwrapped again, this time onto the canvas nodes it covers
   (sub-pixel, so the image is resampled once), shaded, gain-matched and blended.

Each pass reads the LED frames again: from memory or from the run's spill file, where
``pipestitch run`` keeps each one once decoded (pipeline/frame_cache.py; past the spill
file's budget, and for a dataset without that cache, decoded again); holding the strips
instead would make memory grow with the run. Frames that cannot be read, have no pose,
or are not connected to the run by registration or the odometer are reported and skipped.
"""

from __future__ import annotations

import bisect
import functools
import math
from collections import deque
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import NamedTuple, Protocol

import numpy as np

from pipestitch._runtime import scratch
from pipestitch._runtime.memory import release_free_memory
from pipestitch._runtime.threads import ordered_map
from pipestitch.camera import CameraModel
from pipestitch.camera.frames import repair_pixels, to_grey
from pipestitch.errors import DatasetError, StageError
from pipestitch.geometry import PipeSection, Pose, RadiusProfile, WallGrid
from pipestitch.io.dataset import Dataset
from pipestitch.io.imu import read_imu
from pipestitch.io.mask import read_mask
from pipestitch.mosaic.blend import (
    Canvas,
    ShadedStrip,
    canvas_grid,
    frame_grid,
    profile_step,
    shade,
)
from pipestitch.mosaic.flat_field import (
    FlatInput,
    PairRatios,
    RadialFlatField,
    clipped_level,
    flat_input,
    optical_centre_px,
    pair_ratios,
    radial_edges,
    radial_levels,
    unclipped_weight,
)
from pipestitch.mosaic.noise import ContrastNoise, NoiseModel, contrast_noise, estimate_noise
from pipestitch.mosaic.occluders import defect_pixels, occluder_mask
from pipestitch.mosaic.refine import (
    WINDOW_FRAMES,
    PatchShifts,
    node_jacobian,
    pair_jacobians,
    patch_shifts,
    solve_in_windows,
)
from pipestitch.mosaic.register import (
    Link,
    MotionPrior,
    Positions,
    measure_overlap_shift,
    measure_shift,
    polish_moments,
    predict_motion,
    registration_image,
    shared_taper,
    solve_positions,
    spectrum,
)
from pipestitch.mosaic.unwrap import (
    PackedMask,
    Strip,
    UnwrapMaps,
    default_mm_per_px,
    local_contrast_and_mean,
    pack_mask,
    polar_unwrap_maps,
    seen_window_mm,
    strip_window_mm,
    unwrap_maps,
    unwrap_with_quality,
)
from pipestitch.mosaic.wall_profile import frame_profiles
from pipestitch.pipeline.frame_cache import blank_led
from pipestitch.pipeline.pair_timing import (
    SIGNIFICANT,
    led_instant_priors,
    led_share,
    patch_led_share,
    ring_px_per_mm,
)
from pipestitch.pipeline.progress import StageTimer, track
from pipestitch.pipeline.ring_store import StoredRing
from pipestitch.pose.fit import RingPoints
from pipestitch.pose.section import SectionFit, fit_section, sloping_wall_spread
from pipestitch.standards.roll_reference import imu_roll_offset

__all__ = ["UNWRAP_MODES", "ChainLink", "FrameView", "LedSample", "MosaicResult", "MosaicSettings",
           "MosaicSink", "build_mosaic", "find_occluders", "led_frames", "sample_led"]

UNWRAP_MODES = ("ours", "centred", "polar")
Defects = tuple[np.ndarray, ...]   # a sensor's hot and dead pixels: (rows, cols), or ()
LINK_SPAN = 2          # each frame is registered to this many following frames


@dataclass(frozen=True)
class MosaicSettings:
    """How to unwrap and stitch.

    Attributes
    ----------
    mm_per_px : float, optional
        Output scale on the wall (both axes); default from the camera and the pipe
        (:func:`pipestitch.mosaic.unwrap.default_mm_per_px`).
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
    refine_iterations : int
        Registration rounds with photometric pose refinement (``ours`` only; 0 to use
        the ring's poses as they are). Each round costs one more unwrapping pass; one
        round (the default) brings the tilt to a few hundredths of a degree, a second
        to a few thousandths, which the mosaic does not show (``bench/mosaic.py``).
    register_coarsening : int
        All refinement rounds but the last work on strips this many times coarser than
        the mosaic (4x fewer pixels for 2).
    final_coarsening : int
        The same for the last round, whose links place the frames (1: the mosaic's
        scale). Default 2: the placing round on 4x fewer pixels than the mosaic's;
        the frames are still placed to a few hundredths of a millimetre and the stitch
        unwraps onto the canvas at its full scale.
    """

    mm_per_px: float | None = None
    mode: str = "ours"
    workers: int = 2
    step: int = 4
    min_resolution: float = 0.5
    reference_frames: int = 11
    refine_iterations: int = 1
    register_coarsening: int = 2
    final_coarsening: int = 2

    @classmethod
    def fine(cls, **kwargs: object) -> MosaicSettings:
        """Two refinement rounds, the placing one on the mosaic's own scale (``pipestitch
        run --fine-registration``): the tilt to a few thousandths of a degree, at ~1.3x
        the run's time."""
        return cls(**{"refine_iterations": 2, "final_coarsening": 1, **kwargs})

    @property
    def refine_rounds(self) -> int:
        """Rounds of photometric refinement a run makes (``ours`` only); after each,
        the sections are refitted to the frames' ring points."""
        return self.refine_iterations if self.mode == "ours" else 0

    def __post_init__(self) -> None:
        if self.mode not in UNWRAP_MODES:
            raise ValueError(f"mode: expected one of {UNWRAP_MODES}, got {self.mode!r}")
        if self.mm_per_px is not None and not (np.isfinite(self.mm_per_px)
                                               and self.mm_per_px > 0):
            raise ValueError(f"mm_per_px: expected a positive number, got {self.mm_per_px}")


@dataclass(frozen=True, slots=True)
class FrameView:
    """The pose and pipe section a frame is unwrapped with.

    ``alternative`` is the mirror hypothesis of a frame the pose step left ambiguous:
    registration then keeps whichever agrees better with the previous frames.
    ``information`` is the ring's information matrix on (alpha, beta, dx, dy), the
    prior of the photometric refinement; ``refined`` says the pose has been refined.
    ``ring`` keeps the ring points; after each refinement round ``measured`` is the
    section (oval) fitted to them with the refined tilt, which then replaces
    ``section`` and the offset when the pose step fitted an oval (``oval``) or the
    measured ovality is significant. ``profile`` scales the section along the strip
    (the frame's own z) where the other frames' rings say the wall's radius changes
    inside its window (:mod:`pipestitch.mosaic.wall_profile`).
    """

    pose: Pose
    section: PipeSection
    alternative: FrameView | None = None
    information: np.ndarray | None = field(default=None, compare=False)
    refined: bool = False
    ring: RingPoints | StoredRing | None = field(default=None, compare=False)
    oval: bool = False                     # the pose step fitted an oval section
    measured: SectionFit | None = field(default=None, compare=False)
    profile: RadiusProfile | None = field(default=None, compare=False)   # wall along z
    # the ring's information before a wall's slope loosened it (:func:`_on_wall`)
    ring_information: np.ndarray | None = field(default=None, compare=False)
    # the refined pose's 4 x 4 covariance (alpha, beta, dx, dy; rad, mm) from the
    # refinement that gave the pose (mosaic/refine.py; None where it gave none)
    covariance: np.ndarray | None = field(default=None, compare=False)
    # how far out along the rays (px) the LED frame's wall lay from the laser frame's
    # (RingDetection.led_shift_px, NaN where it cannot tell; pipeline/pair_timing.py)
    led_shift_px: float = field(default=math.nan, compare=False)
    # where the pose is the LED frame's: the change (alpha, beta, dx, dy) the rings put
    # between the laser frame's instant and the LED frame's (None: at the laser frame's)
    led_delta: np.ndarray | None = field(default=None, compare=False)


@dataclass
class MosaicResult:
    """Output of :func:`build_mosaic`.

    ``image`` is float (NaN where no data) on ``grid`` (None when the mosaic was
    streamed to a sink); ``skipped`` maps frame -> why;
    ``switched`` says, for each frame the pose step left ambiguous, whether registration
    chose its mirror hypothesis instead; ``chains`` how those frames registered with each
    other as chosen and as mirrored (:class:`ChainLink`).
    """

    grid: WallGrid
    image: np.ndarray | None          # None when streamed to a sink
    weights: np.ndarray | None
    positions: Positions
    links: list[Link]
    radius_mm: float
    window_mm: tuple[float, float]
    placed: list[int]
    skipped: dict[int, str] = field(default_factory=dict)
    gains: dict[int, float] = field(default_factory=dict)
    switched: dict[int, bool] = field(default_factory=dict)
    views: dict[int, FrameView] = field(default_factory=dict)
    chains: list[ChainLink] = field(default_factory=list)
    # the share of a step by which the LED frames follow their laser frames (negative:
    # precede; 0: taken together or not measured): the views' refined poses are the LED
    # frames' where their led_delta says so (pipeline/pair_timing.py), and what told it
    led_share: float = 0.0
    led_share_told: str = ""


@dataclass(frozen=True)
class _Unwrapper:
    camera: CameraModel
    settings: MosaicSettings
    radius_mm: float
    occluded: np.ndarray
    centre: tuple[float, float]     # optical centre (px): the flat field's rings
    edges: np.ndarray               # ring edges (px), mosaic/flat_field.py
    noise: NoiseModel | None = None  # the LED frames' noise (mosaic/noise.py)
    defects: Defects = ()           # the sensor's hot and dead pixels (rows, cols)
    # each frame's clipping level, found on its first unwrap that needs it (a full scan)
    levels: dict[int, float | None] = field(default_factory=dict)

    @functools.cached_property
    def packed_occluded(self) -> PackedMask:
        """``occluded`` as every strip's mask reads it, packed once per run."""
        return pack_mask(self.occluded)

    def clipped(self, index: int, grey: np.ndarray) -> float | None:
        """Frame ``index``'s :func:`~pipestitch.mosaic.flat_field.clipped_level`
        (``grey``: the frame), found once per run."""
        if index not in self.levels:
            self.levels[index] = clipped_level(grey)
        return self.levels[index]

    def maps(self, view: FrameView, grid: WallGrid) -> UnwrapMaps:
        if self.settings.mode == "polar":
            return polar_unwrap_maps(self.camera, self.radius_mm, grid)
        return unwrap_maps(self.camera, view.pose, view.section, grid, step=self.settings.step,
                           with_quality=True, profile=view.profile)

    def strip(self, grey: np.ndarray, view: FrameView, grid: WallGrid
              ) -> tuple[Strip, UnwrapMaps]:
        maps = self.maps(view, grid)
        return unwrap_with_quality(grey, maps, min_resolution=self.settings.min_resolution,
                                   occluded=self.packed_occluded), maps

    def flat(self, index: int, grey: np.ndarray, strip: Strip, maps: UnwrapMaps) -> FlatInput:
        """The strip's nodes as the flat field's pairwise solve takes them."""
        return flat_input(grey, strip.values, strip.shading, strip.weight, maps.map_x,
                          maps.map_y, self.centre, self.edges, self.clipped(index, grey))


def _read_grey(dataset: Dataset, index: int, timer: StageTimer, *,
               scratch_buffer: bool = False, defects: Defects = ()) -> np.ndarray:
    """The LED frame as grey float32, its sensor's ``defects`` (rows, cols) repaired;
    with ``scratch_buffer`` in this thread's buffer (:mod:`pipestitch._runtime.scratch`),
    for a caller done with it before its next frame."""
    with timer("decode"):
        led = dataset.read_led(index)
        if blank := blank_led(dataset, index, led):   # the pose pass took the laser frame alone
            raise DatasetError(dataset.led_paths[index], blank)
        out = (scratch.buffer("mosaic.grey", led.shape[:2], np.float32)
               if scratch_buffer else None)
        grey = to_grey(led, out=out)   # a new array or this thread's buffer
        return repair_pixels(grey, *defects) if len(defects) else grey


NOISE_FRAMES = 3   # LED frames, spread over the run, the noise model is measured on


def _led_noise(dataset: Dataset, frames: Sequence[int], timer: StageTimer) -> NoiseModel | None:
    """The LED frames' noise model (:func:`pipestitch.mosaic.noise.estimate_noise`) from up
    to ``NOISE_FRAMES`` readable frames spread over ``frames``; None without one. For a run
    whose occluder mask is not searched for (:func:`sample_led` measures it otherwise)."""
    if not frames:
        return None
    greys = []
    for i in _spread(frames, NOISE_FRAMES):
        try:
            greys.append(_read_grey(dataset, i, timer))
        except DatasetError:
            continue   # reported when the frame itself is processed
    with timer("register"):
        return estimate_noise(greys)


def _spread(items: Sequence, count: int) -> list:
    """Up to ``count`` of ``items``, evenly spread from the first to the last."""
    if not items:
        return []
    return [items[k] for k in sorted(set(np.linspace(0, len(items) - 1, count)
                                         .round().astype(int)))]


def led_frames(dataset: Dataset) -> list[int]:
    """The pairs whose LED frame the dataset has: the occluder mask's sample, posed or
    not (the arm and the mirror are fixed to the camera whatever the pose)."""
    missing = set(dataset.led_missing())
    return [i for i in range(dataset.n_pairs) if i not in missing]


class LedSample(NamedTuple):
    """What LED frames sampled along a run tell before any is unwrapped."""

    occluded: np.ndarray       # the occluder mask (True: never the wall)
    noise: NoiseModel | None   # the frames' noise model (None: too few blocks to fit one)
    defects: Defects = ()          # the sensor's hot and dead pixels (rows, cols)


def sample_led(dataset: Dataset, frames: Sequence[int], count: int, timer: StageTimer,
               workers: int, *, with_noise: bool = True,
               occluded: np.ndarray | None = None) -> LedSample:
    """Occluder mask (:func:`pipestitch.mosaic.occluders.occluder_mask`; ``occluded``
    when probe.toml names one) and the sensor's stuck pixels
    (:func:`pipestitch.mosaic.occluders.defect_pixels`) from up to ``count`` readable LED
    frames spread over ``frames``, and the frames' noise model
    (:func:`pipestitch.mosaic.noise.estimate_noise`) from ``NOISE_FRAMES`` of the same
    frames (None unless ``with_noise``): each frame is decoded once for all."""
    def read(i: int) -> np.ndarray | None:
        try:
            with timer("decode"):
                led = dataset.read_led(i)
                if blank_led(dataset, i, led):
                    return None   # shows nothing; reported when the frame is processed
                # grey frames as stored (<= 2 bytes a pixel), made float in the mask's
                # stack; colour ones grey now (16-bit BGRA would hold 8 bytes a pixel)
                return led if led.ndim == 2 else to_grey(led)
        except DatasetError:
            return None   # reported when the frame itself is processed

    leds = [f for f in ordered_map(read, _spread(frames, count), workers) if f is not None]
    if not leds:
        raise StageError("no LED frame could be read")
    with timer("occluders"):
        if occluded is None:
            occluded = occluder_mask(leds, workers=workers)
        rows, cols = defect_pixels(leds, occluded)
        seen = ~occluded[rows, cols]   # those the mask takes are never read
        defects = (rows[seen], cols[seen])
    if not with_noise:
        return LedSample(occluded, None, defects)
    with timer("register"):   # one float frame at a time
        noise = estimate_noise(repair_pixels(to_grey(f), *defects)
                               for f in _spread(leds, NOISE_FRAMES))
    return LedSample(occluded, noise, defects)


def find_occluders(dataset: Dataset, frames: Sequence[int], count: int,
                   timer: StageTimer, workers: int) -> np.ndarray:
    """Occluder mask (True: never the wall) from up to ``count`` readable LED frames spread
    over ``frames`` (:func:`sample_led` without the noise model)."""
    return sample_led(dataset, frames, count, timer, workers, with_noise=False).occluded


@dataclass(frozen=True)
class _Candidate:
    """One view of a frame unwrapped for registration."""

    contrast: np.ndarray
    weight: np.ndarray            # the strip's quality weight (float32; 0: no data)
    image: np.ndarray | None      # registration image, its spectrum and polish moments
    spectrum: np.ndarray | None   # (None: the frame's links are known, only patches
    moments: tuple[float, float, float] | None   # are measured)
    flat: FlatInput | None   # None: a pass whose flat field data are not kept
    noise: ContrastNoise | None = None   # of ``contrast``, for the patch shifts


@dataclass(frozen=True)
class _Registered:
    """Pass-1 result of one frame: one candidate per view (two for an ambiguous frame)."""

    index: int
    candidates: list[_Candidate]
    error: str = ""


@dataclass(frozen=True, slots=True)
class ChainLink:
    """Two frames the pose step left ambiguous, registered as chosen and both mirrored.

    ``chosen``: the response of the link between their unwraps as registration chose
    them; ``mirrored``: between their other hypotheses' (0 where that found no link).
    Two consecutive frames on their wrong mirrors warp the wall alike only where their
    poses are alike: along a stretch whose pose changes, the right chain correlates
    better than its mirror (see ``pipestitch.pipeline.run._apply_switches``).
    ``switched_*``: whether each frame was on its mirror hypothesis when measured.
    """

    first: int
    second: int
    chosen: float
    mirrored: float
    switched_first: bool
    switched_second: bool


@dataclass
class _Pass1:
    """What pass 1 gathers over the run."""

    links: list[Link] = field(default_factory=list)
    levels: list[np.ndarray] = field(default_factory=list)
    pairs: list[PairRatios] = field(default_factory=list)

    def add_flat(self, levels: np.ndarray, pairs: list[PairRatios]) -> None:
        """Keep a sampled frame's data for the flat field."""
        self.levels.append(levels)
        self.pairs.extend(pairs)
    done: list[int] = field(default_factory=list)
    switched: dict[int, bool] = field(default_factory=dict)
    patches: list[PatchShifts] = field(default_factory=list)
    chains: list[ChainLink] = field(default_factory=list)
    # undecided frames: how far apart their two unwraps' links put them (dz mm, roll deg);
    # None for a frame with two hypotheses that this pass decided
    spread: dict[int, tuple[float, float] | None] = field(default_factory=dict)


def _merge_spread(spread: dict[int, tuple[float, float]],
                  found: Mapping[int, tuple[float, float] | None]) -> None:
    """``spread`` updated with a pass's: a frame that pass decided is undecided no more."""
    for frame, apart in found.items():
        if apart is None:
            spread.pop(frame, None)
        else:
            spread[frame] = apart


def _widened(link: Link, spread: Mapping[int, tuple[float, float]]) -> Link:
    """``link`` as uncertain as the undecided frames it joins are far apart in their two
    hypotheses (``spread``: :func:`_mirror_spread`)."""
    extra = [spread[f] for f in (link.i, link.j) if f in spread]
    if not extra:
        return link
    return replace(link, dz_sigma_mm=math.hypot(link.dz_sigma_mm, *(e[0] for e in extra)),
                   droll_sigma_deg=math.hypot(link.droll_sigma_deg, *(e[1] for e in extra)))


def _mirror_spread(found: list[list[tuple[Link, _Candidate]]]) -> tuple[float, float] | None:
    """How far apart an undecided frame's two unwraps place it: the largest differences
    of dz and roll between their links to a previous frame both registered with (None
    without one)."""
    first = {ln.i: ln for ln, _ in found[0]}
    apart = [(abs(ln.dz_mm - first[ln.i].dz_mm), abs(ln.droll_deg - first[ln.i].droll_deg))
             for ln, _ in found[1] if ln.i in first]
    if not apart:
        return None
    dz, droll = np.max(np.array(apart), axis=0)
    return float(dz), float(droll)


def _unwrap_candidate(unwrapper: _Unwrapper, index: int, grey: np.ndarray, view: FrameView,
                      grid: WallGrid, timer: StageTimer, *, flat: bool,
                      for_links: bool = True) -> _Candidate:
    """A view of a frame unwrapped for registration: its contrast, and with
    ``for_links`` the registration image its links are found on."""
    with timer("unwrap"):
        strip, maps = unwrapper.strip(grey, view, grid)
    with timer("register"):
        contrast, _, mean = local_contrast_and_mean(strip.values)
        image = registration_image(contrast, strip.weight) if for_links else None
        noise = (None if unwrapper.noise is None
                 else contrast_noise(maps.map_x, maps.map_y, mean, unwrapper.noise))
        return _Candidate(contrast, strip.weight, image,
                          None if image is None else spectrum(image),
                          None if image is None else polish_moments(image),
                          unwrapper.flat(index, grey, strip, maps) if flat else None, noise)


def _link_patches(link: Link, prev: _Candidate, cand: _Candidate, own: WallGrid,
                  timer: StageTimer) -> PatchShifts:
    """The local patch shifts of ``link``'s two strips about its rigid motion."""
    with timer("refine"):
        return patch_shifts(prev.contrast, prev.weight > 0, cand.contrast, cand.weight > 0,
                            (link.droll_deg / own.deg_per_px, link.dz_mm / own.mm_per_px_axial),
                            link.i, link.j, prev.noise)


def _links_to(recent: Sequence[tuple[int, _Candidate]], cand: _Candidate, grid: WallGrid,
              i: int, links: Sequence[Link],
              odometry_mm: Mapping[int, float] | None) -> list[tuple[Link, _Candidate]]:
    found = ((_link(prev, cand, grid, j, i, predict_motion(j, i, links, odometry_mm)), prev)
             for j, prev in recent)
    return [(link, prev) for link, prev in found if link is not None]


def _link(prev: _Candidate, cand: _Candidate, grid: WallGrid, j: int, i: int,
          prior: MotionPrior) -> Link | None:
    """The link from frame ``j`` to ``i``: the whole strips correlated, or, for a step
    to the next frame at which their tapers share less than ``OVERLAP_SHARE`` of their
    energy, only the wall the prior says they share (:func:`measure_overlap_shift`)."""
    if (i - j == 1 and np.isfinite(prior.dz_sigma_mm)
            and shared_taper(grid.n_cols, prior.dz_mm / grid.mm_per_px_axial) < OVERLAP_SHARE):
        return measure_overlap_shift(prev.contrast, prev.weight, cand.contrast, cand.weight,
                                     grid, j, i, prior)
    return measure_shift(prev.image, cand.image, grid, j, i, prior,
                         (prev.spectrum, cand.spectrum), prev.moments)


# Below this share of their tapers' energy in common at the expected step (a step of
# more than ~27 mm in a 58 mm registration strip), consecutive strips are correlated only
# on the wall they share: whole, it sits in their tapers' faint ends. A corroded 65 mm
# wall with 30 mm steps (half size): roll of the links 2.3 deg RMS (max 3.6) -> 0.10,
# z 0.57 -> 0.20 mm RMS (another run: 9 deg of roll at one frame -> 0.14 deg at most).
# Not for smaller steps: at 15-20 mm the
# cut links (or the cut links two frames apart) gave the mirror choice and the solve
# stronger but no better evidence than the whole strips (z worse on two of four runs).
OVERLAP_SHARE = 0.25
MIRROR_RATIO = 1.3     # a hypothesis must correlate this much better to be chosen


def _better_hypothesis(found: list[list[tuple[Link, _Candidate]]]) -> int | None:
    """Which of an ambiguous frame's two unwraps registers clearly better, or None.

    Compared over the previous frames both registered with; the better one needs
    ``MIRROR_RATIO`` times the summed response of the other (near zero tilt the two
    unwraps are nearly the same and their difference is noise: the frame stays
    ambiguous).
    """
    common = {ln.i for ln, _ in found[0]} & {ln.i for ln, _ in found[1]}
    scores = [sum(ln.response for ln, _ in f if ln.i in common) for f in found]
    if not common:
        # Only one hypothesis registered at all: that is evidence too.
        return (0 if found[0] else 1) if (bool(found[0]) != bool(found[1])) else None
    best = int(np.argmax(scores))
    return best if scores[best] >= MIRROR_RATIO * scores[1 - best] else None


def _chain_link(previous: tuple[int, _Candidate | None, bool] | None, alt: _Candidate,
                chosen: Sequence[tuple[Link, _Candidate]], grid: WallGrid, i: int,
                switched: bool, links: Sequence[Link],
                odometry_mm: Mapping[int, float] | None) -> ChainLink | None:
    """Frame ``i``'s :class:`ChainLink` with the frame just before it, when that one too
    was left ambiguous (``previous``: its index, other hypothesis, whether switched):
    the two other hypotheses registered, beside their ``chosen`` link."""
    if previous is None or previous[1] is None or previous[0] != i - 1:
        return None
    j, prev_alt, prev_switched = previous
    mirrored = _link(prev_alt, alt, grid, j, i, predict_motion(j, i, links, odometry_mm))
    response = next((ln.response for ln, _ in chosen if ln.i == j), 0.0)
    return ChainLink(j, i, response, mirrored.response if mirrored else 0.0, prev_switched,
                     switched)


def _register(dataset: Dataset, views: dict[int, FrameView], unwrapper: _Unwrapper,
              own: WallGrid, timer: StageTimer, show_progress: bool,
              skipped: dict[int, str], *, patches: bool, flat: bool,
              seed: Sequence[Link] = ()) -> _Pass1:
    """Pass 1: own-window strips, links to the next frames, and the flat field's data
    (ring levels and overlap ratios) of the frames
    :func:`pipestitch.mosaic.blend.profile_step` samples.

    For a frame left ambiguous by the pose step both hypotheses are unwrapped and the
    one whose strip correlates better with the previous frames is kept (``views`` is
    updated; a frame kept on its first hypothesis keeps the other, so a later, finer
    round can still reverse the choice). With ``patches`` the local patch shifts of
    every link are measured too (for the photometric pose refinement); without
    ``flat``, no flat field data (a round followed by another, which gathers its own).
    ``seed``: links found before ``views``' first frame, for the motion prior of a pass
    over part of the run.
    """
    def work(i: int) -> _Registered:
        try:
            grey = _read_grey(dataset, i, timer, scratch_buffer=True,
                              defects=unwrapper.defects)
        except DatasetError as exc:
            return _Registered(i, [], f"{exc.path.name}: {exc.problem}")
        options = [views[i]] + ([views[i].alternative] if views[i].alternative else [])
        return _Registered(i, [_unwrap_candidate(unwrapper, i, grey, v, own, timer, flat=flat)
                               for v in options])

    def flat_job(cand: _Candidate, found: list[tuple[Link, _Candidate]]
                 ) -> tuple[np.ndarray, list[PairRatios]]:
        """A sampled frame's data for the flat field: its ring levels and its overlaps."""
        with timer("register"):
            levels = radial_levels(cand.flat, len(unwrapper.edges) - 1)
            return levels, [pair_ratios(prev.flat, cand.flat,
                                        (ln.droll_deg / own.deg_per_px,
                                         ln.dz_mm / own.mm_per_px_axial), (ln.i, ln.j))
                            for ln, prev in found]

    out = _Pass1()
    history = list(seed)   # the links the motion prior reads: seed, then this pass's
    recent: deque[tuple[int, _Candidate]] = deque(maxlen=LINK_SPAN)
    # the last frame's other hypothesis, if the pose step left it ambiguous (ChainLink)
    previous_alt: tuple[int, _Candidate | None, bool] | None = None
    order = sorted(views)
    # the flat field's data of the frames it will take, not all (a
    # skipped frame only thins them: still evenly spaced, at most PROFILE_FRAMES)
    level_step = profile_step(len(order))
    workers = unwrapper.settings.workers
    # The links are found in order here (each frame's motion prior and hypothesis
    # choice depend on the links before it); their patch shifts, which nothing else
    # waits for, are measured on a pool of their own, at most 2 per worker pending
    # (memory stays bounded), kept in link order.
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        pending: deque[Future[PatchShifts]] = deque()
        flats: deque[Future[tuple[np.ndarray, list[PairRatios]]]] = deque()
        for reg in track(ordered_map(work, order, workers), "register", total=len(order),
                         enabled=show_progress):
            if not reg.candidates:
                skipped[reg.index] = reg.error
                continue
            with timer("register"):
                found = [_links_to(recent, c, own, reg.index, history, dataset.odometry_mm)
                         for c in reg.candidates]
            best = _better_hypothesis(found) if len(found) > 1 else None
            if len(found) > 1:
                out.spread[reg.index] = _mirror_spread(found) if best is None else None
            if best is not None:
                out.switched[reg.index] = best == 1
                if best == 1:
                    views[reg.index] = views[reg.index].alternative  # type: ignore[assignment]
            cand = reg.candidates[best or 0]
            alt = reg.candidates[1 - (best or 0)] if len(reg.candidates) > 1 else None
            if alt is not None:
                with timer("register"):
                    chain = _chain_link(previous_alt, alt, found[best or 0], own, reg.index,
                                        best == 1, history, dataset.odometry_mm)
                if chain is not None:
                    out.chains.append(chain)
            sampled = len(out.done) % level_step == 0
            for link, prev in found[best or 0]:
                out.links.append(link)
                history.append(link)
                if patches:
                    pending.append(pool.submit(_link_patches, link, prev, cand, own, timer))
            if sampled and flat:
                flats.append(pool.submit(flat_job, cand, found[best or 0]))
            while len(pending) > 2 * max(1, workers):
                out.patches.append(pending.popleft().result())
            while len(flats) > 2 * max(1, workers):
                out.add_flat(*flats.popleft().result())
            recent.append((reg.index, cand))
            previous_alt = (reg.index, alt, best == 1)
            out.done.append(reg.index)
        out.patches.extend(f.result() for f in pending)
        for f in flats:
            out.add_flat(*f.result())
    return out


def _refine_views(views: dict[int, FrameView], patches: Sequence[PatchShifts],
                  links: Sequence[Link], camera: CameraModel, own: WallGrid,
                  redo: Collection[int] | None = None, share: float = 0.0,
                  ) -> tuple[dict[int, FrameView], list[Link]]:
    """Views with poses corrected by the photometric refinement, and corrected links.

    A link with patches is replaced by the pair's rigid motion from the refinement
    (free of the warp the old poses left in the strips); the others are kept. With
    ``redo``, only those frames' poses are corrected: the other frames the patches
    reach are held where they are. With ``share`` (the LED frames taken that share of
    a step after their laser frames: :func:`pipestitch.pipeline.pair_timing.led_share`)
    the frames not refined yet take their rings' prior at their LED frames' instant
    (:func:`pipestitch.pipeline.pair_timing.led_instant_priors`), and keep that prior.
    """
    solved = views if redo is None else {f: views[f] for o in patches for f in (o.i, o.j)}
    held = set() if redo is None else set(solved) - set(redo)
    fresh = {i: v for i, v in solved.items() if not v.refined}
    # a neighbour whose mirror is undecided stands in with its chosen pose: near zero
    # tilt, where mirrors are undecided, the two differ little (leaving such neighbours
    # out moved their neighbours' priors not at all: 0.19 deg at worst on 30 corroded
    # pairs 0.2 of a step apart, against 0.03)
    information, centre = led_instant_priors({i: v.pose for i, v in fresh.items()},
                                             {i: v.information for i, v in solved.items()},
                                             share)

    jacobian = _jacobian_of(views, camera, own, held)
    covariances: dict[int, np.ndarray] = {}
    errors, motions = solve_in_windows(patches, lambda new: pair_jacobians(new, jacobian),
                                       information, held=held, covariances=covariances,
                                       prior_errors=centre)
    links = [replace(ln, dz_mm=float(motions[(ln.i, ln.j)][1] * own.mm_per_px_axial),
                     droll_deg=float(motions[(ln.i, ln.j)][0] * own.deg_per_px))
             if (ln.i, ln.j) in motions and np.all(np.isfinite(motions[(ln.i, ln.j)])) else ln
             for ln in links]
    out = dict(views)
    for i, v in views.items() if redo is None else ((f, views[f]) for f in redo):
        # a covariance from this solve only (none: the ring's sigma is stated)
        e, covariance = errors.get(i, np.zeros(4)), covariances.get(i)
        delta = -centre[i] if i in centre else v.led_delta
        if not np.all(np.isfinite(e)):
            # keep the ring's pose rather than lose the frame
            e, covariance, delta = np.zeros(4), v.covariance, None
        p = v.pose
        out[i] = replace(v, pose=Pose(p.alpha - e[0], p.beta - e[1], p.dx_mm - e[2],
                                      p.dy_mm - e[3]), refined=True, covariance=covariance,
                         information=information.get(i, v.information),
                         led_delta=delta)
        if i in centre:   # the prior at the LED frame's instant is its prior from now on
            out[i] = replace(out[i], ring_information=out[i].information)
    return out, links


# Ovality this far above its uncertainty (and at least this large) is taken as real:
# the view is then unwrapped with the oval section.
OVAL_SIGNIFICANCE = 5.0
OVAL_MIN = 0.005


def _refit_section(view: FrameView) -> FrameView:
    """The view with its section fitted to the ring at the refined tilt (see FrameView).

    An adopted oval brings its offset, and its information (section marginalised) as
    the next round's prior: the circle fit's would claim a tilt the ovality biased.
    """
    if view.ring is None or not view.refined:
        return view
    start = view.measured.section if view.measured is not None else view.section
    points = view.ring.points_mm   # outside the try: a store that fails must say so
    try:
        measured = fit_section(points, view.pose, view.section.mean_radius_mm, start=start,
                               noise_mm=view.ring.noise_mm)
    except ValueError:   # no valid section (degenerate ring points): keep the view
        return view
    # Kept for the whole run: the per-point residuals (~6 kB a frame) are not read again.
    measured = replace(measured, residuals_mm=measured.residuals_mm[:0].copy())
    oval = measured.section.ovality
    if view.oval or oval > max(OVAL_SIGNIFICANCE * measured.ovality_std, OVAL_MIN):
        pose = measured.pose
        if view.led_delta is not None:   # offsets fitted to the laser frame's ring points
            pose = replace(pose, dx_mm=pose.dx_mm + view.led_delta[2],
                           dy_mm=pose.dy_mm + view.led_delta[3])
        return replace(view, pose=pose, section=measured.section, measured=measured,
                       information=measured.information, oval=True)
    return replace(view, measured=measured)


@dataclass
class _Registration:
    """What the registration rounds leave for the stitch: per frame only its view and
    links (the patch shifts and flat field data of the passes are dropped)."""

    views: dict[int, FrameView]
    links: list[Link]
    done: list[int]
    switched: dict[int, bool]
    flat_field: RadialFlatField     # from the last pass's levels
    chains: list[ChainLink]         # the latest measured of each pair
    spread: dict[int, tuple[float, float]] = field(default_factory=dict)   # _mirror_spread
    led_share: float = 0.0          # as MosaicResult.led_share
    led_share_told: str = ""        # as MosaicResult.led_share_told


def _measured_led_share(dataset: Dataset, views: Mapping[int, FrameView],
                        links: Sequence[Link], camera: CameraModel,
                        patches: Sequence[PatchShifts], own: WallGrid) -> tuple[float, str]:
    """The share of a step by which the run's LED frames follow their laser frames, and
    what told it: the wall under the laser line where it tells
    (:func:`pipestitch.pipeline.pair_timing.led_share`), else the LED frames' patches
    of the first refinement window's frames (the camera's frame timing is the run's:
    :func:`pipestitch.pipeline.pair_timing.patch_led_share`), where that share is
    ``SIGNIFICANT`` sigmas from 0; else 0."""
    radius = dataset.config.pipe.inner_diameter_mm / 2
    px_per_mm = ring_px_per_mm(camera, dataset.config.laser.plane_distance_mm, radius)
    share = led_share({i: v.led_shift_px for i, v in views.items()}, links, px_per_mm)
    if share is not None:
        return share, LINE_TELLS
    first = {i: views[i] for i in sorted(views)[:WINDOW_FRAMES]}
    obs = [o for o in patches if o.i in first and o.j in first and len(o.nodes)]
    jacobians = pair_jacobians(obs, _jacobian_of(first, camera, own))
    share, sigma = patch_led_share({i: v.pose for i, v in first.items()},
                                   {i: v.information for i, v in first.items()}, obs,
                                   dict(zip([(o.i, o.j) for o in obs], jacobians, strict=True)))
    return (share, PATCHES_TELL) if abs(share) > SIGNIFICANT * sigma else (0.0, "")


# what told the share, as the run's message says it
LINE_TELLS = "measured on the wall under the laser line"
PATCHES_TELL = "measured from the LED frames' overlaps against the rings' poses"


def _jacobian_of(views: Mapping[int, FrameView], camera: CameraModel, own: WallGrid,
                 held: Collection[int] = ()) -> Callable[[int, np.ndarray], np.ndarray]:
    """The Jacobian of a frame's strip nodes on its pose (:func:`node_jacobian`, float32:
    a window's links' Jacobians are held for its solve); zero for a ``held`` frame,
    whose Jacobian the solve does not read (refine.solve_pose_errors): not computed."""
    def jacobian(frame: int, nodes: np.ndarray) -> np.ndarray:
        if frame in held:
            return np.zeros((len(nodes), 2, 4), np.float32)
        view = views[frame]
        return node_jacobian(camera, view.pose, view.section, own, nodes).astype(np.float32)
    return jacobian


def _registration_rounds(dataset: Dataset, views: dict[int, FrameView], unwrapper: _Unwrapper,
                         grids: tuple[WallGrid, WallGrid], rounds: int, timer: StageTimer,
                         show_progress: bool, skipped: dict[int, str]) -> _Registration:
    """Registration passes with photometric refinement between them.

    Early rounds on ``grids[0]``, the last (whose links place the frames) on
    ``grids[1]``. The refinement is linearised about the poses it starts from: a frame
    whose tilt it corrects by a degree comes out a few hundredths of a degree off (an
    oval pipe's frames, whose tilt the ring leaves at 0; frames near zero tilt, where
    the ring measures it worst), and a frame it finds oval was registered as a circle.
    So when the last round moved some frame's tilt by more than ``LINEAR_TILT_DEG`` or
    found frames oval, the frames it moved by more than ``REDO_TILT_DEG``, the new
    ovals and the frames that still have a mirror hypothesis are registered again
    (:func:`_register_again`: strips of them and of the neighbours they link to; both
    hypotheses only of a frame registration left undecided, :func:`_undecided`) and
    refined once more, their neighbours held. The frames it moved less keep one
    round's accuracy (0.01-0.03 degrees on a corroded run against 0.004-0.02 after a
    whole second round, docs/benchmarks.md). Each pass's patch shifts are released
    once the refinement has used them, and only the last planned round's flat field
    data are kept, reduced to the flat field at once (earlier rounds do not gather
    them; the frames registered again do not replace them, though they were measured
    on strips from the poses before the correction).
    """
    camera, switched = unwrapper.camera, {}
    chains: dict[tuple[int, int], ChainLink] = {}
    spread: dict[int, tuple[float, float]] = {}
    before, share, told = views, 0.0, ""
    for k in range(max(1, rounds)):
        own = grids[0] if k < rounds - 1 else grids[1]
        release_free_memory()   # each pass starts from what is live (_runtime/memory.py)
        pass1 = _register(dataset, views, unwrapper, own, timer, show_progress, skipped,
                          patches=rounds > 0, flat=k >= rounds - 1)
        switched.update(pass1.switched)
        _merge_spread(spread, pass1.spread)
        chains.update(((c.first, c.second), c) for c in pass1.chains)
        links, done, levels, pairs = pass1.links, pass1.done, pass1.levels, pass1.pairs
        before = views
        if pass1.patches:
            with timer("refine"):
                if k == 0:   # on the rings' poses, before any refinement
                    share, told = _measured_led_share(dataset, views, links, camera,
                                                      pass1.patches, own)
                views, links = _refine_views(views, pass1.patches, links, camera, own,
                                             share=share if k == 0 else 0.0)
                views = {i: _refit_section(v) for i, v in views.items()}
        del pass1   # its patches: before the next pass gathers its own
    redo = _frames_to_redo(before, views)
    if redo:
        # and the frames that still have a mirror hypothesis: a full round would let
        # registration choose again between their two
        redo = sorted({*redo, *(i for i in done if views[i].alternative is not None)})
        release_free_memory()
        views, links, patches = _register_again(dataset, views, unwrapper, grids[1], timer,
                                                skipped, links, done, redo, switched,
                                                chains, spread)
        again = set(redo)
        with timer("refine"):
            views, links = _refine_views(views, patches, links, camera, grids[1], again)
            views = {i: _refit_section(v) if i in again else v for i, v in views.items()}
        del patches
    # The ring points served the section refits: the stitch and the outputs do not
    # read them (~6 kB a frame, 24 MB at 4000 pairs).
    views = {i: _without_ring(v) for i, v in views.items()}
    flat = (RadialFlatField.from_pairs(pairs, unwrapper.edges, unwrapper.centre)
            or RadialFlatField.from_levels(levels, unwrapper.edges, unwrapper.centre))
    return _Registration(views, links, done, switched, flat, list(chains.values()), spread,
                         share, told)


LINEAR_TILT_DEG = 1.0   # after a round that corrects a tilt by more, frames are redone:
REDO_TILT_DEG = 0.25    # those it corrected by more than this


def _frames_to_redo(before: Mapping[int, FrameView], after: Mapping[int, FrameView]
                    ) -> list[int]:
    """The frames a refinement round left worth one more (see _registration_rounds):
    none unless it moved some tilt by more than ``LINEAR_TILT_DEG`` or found a frame
    oval; then those moved by more than ``REDO_TILT_DEG`` and the new ovals."""
    moved, oval = {}, []
    for i, v in after.items():
        b = before.get(i)
        if b is None:
            continue
        tilt = max(abs(v.pose.alpha - b.pose.alpha), abs(v.pose.beta - b.pose.beta))
        moved[i] = float(np.rad2deg(tilt))
        if v.oval and not b.oval:
            oval.append(i)
    if not oval and max(moved.values(), default=0.0) <= LINEAR_TILT_DEG:
        return []
    return sorted({i for i, m in moved.items() if m > REDO_TILT_DEG} | set(oval))


def _segments(done: Sequence[int], frames: Collection[int], span: int) -> list[list[int]]:
    """Runs of consecutive registered frames (``done``, in order) that hold each of
    ``frames`` with ``span`` registered frames on each side."""
    position = {f: k for k, f in enumerate(done)}
    kept = sorted({k for f in frames if f in position
                   for k in range(max(0, position[f] - span),
                                  min(len(done), position[f] + span + 1))})
    runs: list[list[int]] = []
    for k in kept:
        if runs and k == position[runs[-1][-1]] + 1:
            runs[-1].append(done[k])
        else:
            runs.append([done[k]])
    return runs


SEED_LINKS = 8 * LINK_SPAN   # links before a run: more than predict_motion's 5 steps


def _undecided(views: Mapping[int, FrameView], frames: Iterable[int],
               switched: Mapping[int, bool]) -> list[int]:
    """Those of ``frames`` that have a mirror hypothesis registration has not decided
    (``switched`` holds the decided ones).

    A decided frame is not registered again with both: its chosen view carries the
    refined pose and its mirror the ring's alone, so the two would be weighed unequally.
    On 1000 corroded half-size pairs (seed 0) registering them again changed no choice;
    the redo there now registers 118 frames again instead of 462.
    """
    return [i for i in frames if views[i].alternative is not None and i not in switched]


def _register_again(dataset: Dataset, views: dict[int, FrameView], unwrapper: _Unwrapper,
                    own: WallGrid, timer: StageTimer, skipped: dict[int, str],
                    links: list[Link], done: list[int], redo: Sequence[int],
                    switched: dict[int, bool], chains: dict[tuple[int, int], ChainLink],
                    spread: dict[int, tuple[float, float]],
                    ) -> tuple[dict[int, FrameView], list[Link], list[PatchShifts]]:
    """The links of the ``redo`` frames measured again on strips from the current views.

    A redone frame with a mirror hypothesis no registration has decided
    (:func:`_undecided`) is registered as a full round would
    (links, hypothesis choice, patch shifts: :func:`_register`) in a run of the run
    that reaches ``LINK_SPAN`` registered frames beyond it, and the run's links
    replace its old ones. For the other links of the redone frames only the patch
    shifts are measured again, about the links the refinement left
    (:func:`_repatch`): their rigid part is the refinement's already, and the
    whole-strip correlation that would find it again is the costly part of a round.

    Returns the views (hypotheses chosen now applied, ``switched``, ``chains`` and
    ``spread`` updated), the links and the patch shifts measured.
    """
    views, patches, new = dict(views), [], []
    runs = _segments(done, _undecided(views, redo, switched), LINK_SPAN)
    run_of = {f: k for k, run in enumerate(runs) for f in run}
    ends = [ln.j for ln in links]   # in order (as _register found them)
    for run in runs:
        part = {i: views[i] for i in run}
        # the motion prior reads the last few consecutive steps before the run
        first = bisect.bisect_right(ends, run[0])
        seed = links[max(0, first - SEED_LINKS):first]
        found = _register(dataset, part, unwrapper, own, timer, False, skipped,
                          patches=True, flat=False, seed=seed)
        views.update(part)
        switched.update(found.switched)
        chains.update(((c.first, c.second), c) for c in found.chains)
        new.extend(found.links)
        _merge_spread(spread, found.spread)
        patches.extend(found.patches)
    kept = [ln for ln in links
            if not (ln.i in run_of and run_of[ln.i] == run_of.get(ln.j))] + new
    measured = {(ln.i, ln.j) for ln in new}
    wanted = set(redo)
    todo = [ln for ln in kept if (ln.i in wanted or ln.j in wanted)
            and (ln.i, ln.j) not in measured]
    patches.extend(_repatch(dataset, views, unwrapper, own, todo, timer))
    return views, sorted(kept, key=lambda ln: (ln.j, ln.i)), patches


def _repatch(dataset: Dataset, views: Mapping[int, FrameView], unwrapper: _Unwrapper,
             own: WallGrid, links: Sequence[Link], timer: StageTimer) -> list[PatchShifts]:
    """The patch shifts of ``links``, measured again on strips unwrapped with ``views``
    about the links' rigid motions.

    The frames are read in order and each strip is held only until its last link is
    measured; a frame that cannot be read now leaves its links without patches (the
    stitch reports it).
    """
    if not links:   # every redone frame's links were registered again in its run
        return []
    ending: dict[int, list[Link]] = {}
    last_use: dict[int, int] = {}
    for ln in links:
        ending.setdefault(ln.j, []).append(ln)
        last_use[ln.i] = max(last_use.get(ln.i, ln.i), ln.j)

    def work(i: int) -> tuple[int, _Candidate | None]:
        try:
            grey = _read_grey(dataset, i, timer, scratch_buffer=True,
                              defects=unwrapper.defects)
        except DatasetError:
            return i, None
        return i, _unwrap_candidate(unwrapper, i, grey, views[i], own, timer, flat=False,
                                    for_links=False)

    frames = sorted({f for ln in links for f in (ln.i, ln.j)})
    workers = unwrapper.settings.workers
    strips: dict[int, _Candidate] = {}
    out: list[PatchShifts] = []
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        pending: deque[Future[PatchShifts]] = deque()
        for i, strip in ordered_map(work, frames, workers):
            if strip is not None:
                strips[i] = strip
                pending.extend(pool.submit(_link_patches, ln, strips[ln.i], strip, own, timer)
                               for ln in ending.get(i, []) if ln.i in strips)
            for f in [f for f in strips if last_use.get(f, f) <= i]:
                del strips[f]
            while len(pending) > 2 * max(1, workers):
                out.append(pending.popleft().result())
        out.extend(f.result() for f in pending)
    return out


def _without_ring(view: FrameView) -> FrameView:
    """The view (and its mirror alternative) without the ring points."""
    alternative = view.alternative and replace(view.alternative, ring=None)
    return replace(view, ring=None, alternative=alternative)


RELEASE_COLS = 512     # the canvas releases finished columns in blocks of at least this


class MosaicSink(Protocol):
    """Where a streamed mosaic goes (see :func:`build_mosaic`)."""

    def start(self, grid: WallGrid, radius_mm: float) -> None:
        """Called once, before any column, with the canvas grid and the pipe radius."""

    def push(self, col0: int, image: np.ndarray, weights: np.ndarray) -> None:
        """Finished columns ``col0 ..``, left to right (float, NaN where no data)."""


def _release_points(canvas: WallGrid, positions: Positions, placed: list[int],
                    window: tuple[float, float]) -> list[int]:
    """For each placed frame, the canvas columns no later frame reaches (all before it)."""
    firsts = [frame_grid(canvas, positions.z_mm[i], positions.roll_deg[i], window)[1]
              for i in placed]
    later = np.minimum.accumulate(np.array(firsts[::-1] or [0]))[::-1]
    return [int(c) for c in later[1:]] + [canvas.n_cols]


def _stitch(dataset: Dataset, views: Mapping[int, FrameView], unwrapper: _Unwrapper,
            positions: Positions, placed: list[int], canvas: Canvas, window: tuple[float, float],
            flat: RadialFlatField, timer: StageTimer,
            show_progress: bool, skipped: dict[int, str],
            sink: MosaicSink | None) -> dict[int, float]:
    """Pass 2: every placed frame onto the canvas nodes it covers.

    With a ``sink``, the columns no later frame reaches are released to it after each
    frame (in blocks of at least ``RELEASE_COLS``), so the canvas holds only the frames
    in flight.
    """
    def work(i: int) -> tuple[int, ShadedStrip | None, int, str]:
        grid, col = frame_grid(canvas.grid, positions.z_mm[i], positions.roll_deg[i], window)
        try:
            grey = _read_grey(dataset, i, timer, scratch_buffer=True,
                              defects=unwrapper.defects)
        except DatasetError as exc:  # readable in pass 1: changed on disk since
            return i, None, col, f"{exc.path.name}: {exc.problem}"
        with timer("unwrap"):
            strip, maps = unwrapper.strip(grey, views[i], grid)
        with timer("blend"):
            lit = replace(strip, shading=flat.at(maps.map_x, maps.map_y, strip.shading),
                          weight=unclipped_weight(grey, maps.map_x, maps.map_y, strip.weight,
                                                  unwrapper.clipped(i, grey)))
            return i, shade(lit), col, ""

    gains = {}
    release = _release_points(canvas.grid, positions, placed, window)
    # Unwrapping and shading run on the workers; only the blend, whose gain depends on
    # the strips before, waits for them here in order.
    frames = ordered_map(work, placed, unwrapper.settings.workers)
    for k, (i, shaded, col, error) in enumerate(track(frames, "stitch", total=len(placed),
                                                      enabled=show_progress)):
        if shaded is not None:
            with timer("blend"):
                gains[i] = canvas.blend(shaded, col)
        else:
            skipped[i] = error
        if sink is not None and (release[k] - canvas.first >= RELEASE_COLS
                                 or k == len(placed) - 1):
            with timer("blend"):
                block = canvas.release(release[k])
            if block is not None:
                sink.push(*block)
    return gains


def _views(poses: Mapping[int, FrameView], mode: str,
           nominal_radius_mm: float) -> dict[int, FrameView]:
    if mode == "ours":
        return dict(poses)
    return {i: FrameView(Pose(), PipeSection(nominal_radius_mm)) for i in poses}


def _windows(camera: CameraModel, views: Mapping[int, FrameView], radius_mm: float,
             mm_per_px: float, settings: MosaicSettings,
             occluded: np.ndarray) -> dict[int, tuple[float, float]]:
    """Axial window of the strips at each coarsening the run uses (1: the canvas').

    The centred camera's window at the canvas' scale (:func:`strip_window_mm`), cut to
    what the run's frames resolve outside the ``occluded`` pixels at each scale
    (:func:`seen_window_mm`; both hypotheses of an ambiguous frame). The polar
    baseline keeps the centred window: its maps ignore the poses.
    """
    window = strip_window_mm(camera, radius_mm, mm_per_px, min_resolution=settings.min_resolution)
    scales = {1, settings.final_coarsening, settings.register_coarsening}
    if settings.mode == "polar":
        return dict.fromkeys(scales, window)
    seen = [(w.pose, w.section) for v in views.values() for w in (v, v.alternative)
            if w is not None]
    return {k: seen_window_mm(camera, seen, radius_mm, mm_per_px * k, window,
                              min_resolution=settings.min_resolution, occluded=occluded)
            for k in scales}


def _check_positions(positions: Positions | None, n_frames: int) -> None:
    """Refuse known positions that do not give z and roll for each of the run's frames."""
    if positions is None:
        return
    shapes = (np.shape(positions.z_mm), np.shape(positions.roll_deg))
    if any(shape != (n_frames,) for shape in shapes):
        raise ValueError(f"positions: expected z_mm and roll_deg of shape ({n_frames},) (one "
                         f"per frame of the run), got {shapes[0]} and {shapes[1]}")


def _roll_from_imu(positions: Positions, imu_roll_deg: Mapping[int, float] | None) -> Positions:
    """``positions`` with the roll made the IMU's (SPEC's gamma against gravity) where the
    dataset has an imu.csv: registration measures roll up to one offset, the IMU fixes it
    (its circular mean over the frames both know), as the odometer fixes z. The mosaic's
    theta is then the pipe frame's, crown at 270 deg."""
    if not imu_roll_deg:
        return positions
    guessed = set(positions.roll_guessed)   # interpolated, not registered: no measure of c
    roll = {i: float(r) for i, r in enumerate(positions.roll_deg)
            if np.isfinite(r) and i not in guessed}
    found = imu_roll_offset(roll, imu_roll_deg)
    if found is None:
        return positions
    return replace(positions, roll_deg=positions.roll_deg + found[0], roll_reference="imu")


def _solved(dataset: Dataset, reg: _Registration) -> Positions:
    """The positions solved from the links and the odometer. Where the solve gave up an
    odometer increment beside an undecided frame (:func:`_mirror_spread`), that frame's
    links are taken as uncertain as its two hypotheses are far apart and the run solved
    again: on its wrong mirror a frame's strip is warped, and its links are
    precise but off by about as much (20 mm steps: 2-3.5 mm against an odometer good to
    0.3 mm). Links that agree with the odometer keep their own sigma: there the two
    hypotheses differ by less than the odometer's noise, which would only blur z."""
    positions = solve_positions(dataset.n_pairs, reg.links, odometry_mm=dataset.odometry_mm,
                                placed=reg.done)
    given_up = [(i, j) for i, j, src in positions.outliers if src == "odometer"]
    doubted = {f: reg.spread[f] for pair in given_up for f in pair if f in reg.spread}
    if not doubted:
        return positions
    # The odometer's noise as the links measured it before any was widened (it is at
    # least the links' median sigma, which the widened ones would inflate).
    again = solve_positions(dataset.n_pairs, [_widened(ln, doubted) for ln in reg.links],
                            odometry_mm=dataset.odometry_mm, placed=reg.done,
                            odometer_sigma_mm=positions.odometer_sigma_mm)
    placed = [np.isfinite(p.z_mm).sum() for p in (positions, again)]
    kept_up = sum(src == "odometer" for _, _, src in again.outliers)
    # kept only where it keeps more of the odometer and places no fewer frames
    return again if kept_up < len(given_up) and placed[1] >= placed[0] else positions


def _placing(dataset: Dataset, reg: _Registration, given: Positions | None,
             skipped: dict[int, str], timer: StageTimer,
             imu_roll_deg: Mapping[int, float] | None) -> tuple[Positions, list[int]]:
    """The run's positions and the registered frames they place.

    The positions are solved from the registration links and the odometer, or are the
    ``given`` ones. Registered frames left without a finite z and roll are reported in
    ``skipped``.

    Raises
    ------
    StageError
        When no frame can be placed.
    """
    if given is None:
        with timer("register"):
            positions = _solved(dataset, reg)
            positions = _roll_from_imu(positions, imu_roll_deg)
        why = "not registered to the run (no common texture, no odometer)"
    else:
        positions, why = given, "no position given for the frame"
    placed = [i for i in reg.done
              if np.isfinite(positions.z_mm[i]) and np.isfinite(positions.roll_deg[i])]
    for i in sorted(set(reg.done) - set(placed)):
        skipped[i] = why
    for i in placed:   # placed now, after an earlier placing of the run had not
        if skipped.get(i) == why:
            del skipped[i]
    if not placed:
        raise StageError("no frame could be placed in the mosaic")
    return positions, placed


def _on_wall(view: FrameView, profile: RadiusProfile | None, ahead_mm: float) -> FrameView:
    """The view unwrapped onto ``profile``, its ring's prior loosened by what a ring on a
    sloping wall misleads its fit by.

    The ring fit takes the wall at the ring for a cylinder; on a sloping wall it is off
    by up to :func:`pipestitch.pose.section.sloping_wall_spread`. That is added to the
    prior's covariance (Woodbury: (I^-1 + S)^-1 = I - I (S^-1 + I)^-1 I); the photometric
    links then place the frame (a reducer's ring frames: 0.28 -> 0.01 degrees). Each
    round loosens the ring's own information (``ring_information``), not the last one's.
    """
    info = view.ring_information if view.ring_information is not None else view.information
    viewed = replace(view, profile=profile, information=info, ring_information=info)
    if profile is None or info is None or not np.all(np.isfinite(info)):
        return viewed
    radius = view.section.mean_radius_mm
    slope = radius * abs(float(profile.at(ahead_mm + 0.5) - profile.at(ahead_mm - 0.5)))
    spread = sloping_wall_spread(slope, radius, view.pose, ahead_mm) ** 2
    if spread[2] <= 0:
        return viewed
    loosened = info - info @ np.linalg.solve(np.diag(1.0 / spread) + info, info)
    return replace(viewed, information=0.5 * (loosened + loosened.T))


def _same_wall(a: RadiusProfile | None, b: RadiusProfile | None) -> bool:
    if a is None or b is None:
        return a is b
    return np.array_equal(a.z_mm, b.z_mm) and np.array_equal(a.scale, b.scale)


# Rounds of wall profiles and the registration of their frames: the profiles are placed
# by the positions the previous round solved (a reducer: 0.94 -> 0.08 -> 0.02 mm).
PROFILE_ROUNDS = 3


def _with_wall_profiles(dataset: Dataset, reg: _Registration, positions: Positions,
                        unwrapper: _Unwrapper, own: WallGrid, window: tuple[float, float],
                        timer: StageTimer, skipped: dict[int, str], *, again: bool,
                        given: Mapping[int, RadiusProfile]
                        ) -> tuple[_Registration, list[int]]:
    """The registration with each view's wall along its strip, where the rings of the
    frames placed there say the pipe's radius changes inside its window
    (:func:`frame_profiles`; else the caller's ``given`` one), and the frames measured
    again. ``again``, when some wall changed, the links and poses of the run are
    measured again on the strips unwrapped onto those walls (:func:`_register_again`:
    patch shifts about the links, then the refinement), so the positions solved from
    them follow."""
    views = reg.views
    z = {i: float(positions.z_mm[i]) for i in reg.done if np.isfinite(positions.z_mm[i])}
    radius = {i: views[i].section.mean_radius_mm for i in z}
    profiles = {**given, **frame_profiles(z, radius, dataset.config.laser.plane_distance_mm,
                                          window, step_mm=own.mm_per_px_axial)}
    if all(_same_wall(v.profile, profiles.get(i)) for i, v in views.items()):
        return reg, []
    ahead = dataset.config.laser.plane_distance_mm

    def on_wall(i: int, v: FrameView) -> FrameView:
        walled = _on_wall(v, profiles.get(i), ahead)
        if v.alternative is None:
            return walled
        return replace(walled, alternative=_on_wall(v.alternative, profiles.get(i), ahead))

    views = {i: on_wall(i, v) for i, v in views.items()}
    if not again:
        return replace(reg, views=views), []
    # Every frame, not only those given a wall: the refinement solves the run's tilts
    # together, and the links of strips unwrapped onto the wrong wall bent them all
    # (a reducer mid-run: 0.1-0.3 degrees at every frame, 0.005 without it).
    redo = list(reg.done)
    switched, chains = dict(reg.switched), {(c.first, c.second): c for c in reg.chains}
    spread = dict(reg.spread)
    views, links, patches = _register_again(dataset, views, unwrapper, own, timer, skipped,
                                            reg.links, reg.done, redo, switched, chains, spread)
    with timer("refine"):
        views, links = _refine_views(views, patches, links, unwrapper.camera, own, set(redo))
    return replace(reg, views=views, links=links, switched=switched,
                   chains=list(chains.values()), spread=spread), redo


def build_mosaic(dataset: Dataset, poses: Mapping[int, FrameView],
                 settings: MosaicSettings, *, timer: StageTimer | None = None,
                 show_progress: bool = True, sink: MosaicSink | None = None,
                 positions: Positions | None = None,
                 occluded: np.ndarray | None = None,
                 noise: NoiseModel | None = None, defects: Defects = ()) -> MosaicResult:
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
    sink : MosaicSink, optional
        Streams the mosaic: finished columns go to the sink as the stitching proceeds
        and the result holds no image (``image`` and ``weights`` are None). Without a
        sink the whole mosaic is returned.
    positions : Positions, optional
        Known axial position and roll of every frame of the run (arrays of
        ``dataset.n_pairs``; from a survey, or the simulator's truth). The registration
        passes still run (they measure the flat field the stitch divides by), but the
        frames are placed at these positions instead of the ones solved from the links
        and the odometer, and the result's ``positions`` are these. A frame whose given
        z or roll is NaN is reported in ``skipped``. Default: solved.
    occluded : numpy.ndarray, optional
        The camera's occluded pixels (bool, the frames' shape; True: never the wall),
        when the caller has them already (``pipestitch run`` finds them while the poses
        are fitted). Default: probe.toml's mask, else found from the LED frames
        (:func:`sample_led` over :func:`led_frames`).
    noise : NoiseModel, optional
        The LED frames' noise model, when the caller has measured it with ``occluded``
        (:func:`sample_led`). Default: measured here, from the occluders' sample, else
        from a few of the posed frames.
    defects : tuple of numpy.ndarray, optional
        The sensor's hot and dead pixels (rows, cols: :func:`sample_led`), repaired in
        every LED frame read; found here with the occluders when they are.

    Returns
    -------
    MosaicResult
        The mosaic, the frames' positions, the placed frames and why the others were
        skipped.

    Raises
    ------
    DatasetError
        When the dataset has no LED frames.
    StageError
        When no frame has both a pose and an LED frame, or none can be placed.
    ValueError
        When ``positions`` does not give one z and roll per frame of the run.
    """
    timer = timer or StageTimer()
    _check_positions(positions, dataset.n_pairs)
    if not dataset.has_led:
        raise DatasetError(dataset.root / "frames", "no LED frames: nothing to stitch")
    camera = dataset.config.camera_model()
    nominal = dataset.config.pipe.inner_diameter_mm / 2
    radii = [v.section.mean_radius_mm for v in poses.values()]
    radius = float(np.median(radii)) if radii and settings.mode == "ours" else nominal
    mm = settings.mm_per_px or default_mm_per_px(camera, radius)
    skipped: dict[int, str] = {i: "no LED frame" for i in dataset.led_missing() if i in poses}
    usable = {i: p for i, p in poses.items() if i not in skipped}
    if not usable:
        raise StageError("no frame has both a pose and an LED frame")
    views = _views(usable, settings.mode, nominal)
    if occluded is None:
        occluded = read_mask(dataset.root, dataset.config)   # probe.toml's, else found
    if occluded is None:
        occluded, noise, defects = sample_led(dataset, led_frames(dataset),
                                              settings.reference_frames, timer,
                                              settings.workers)
    with timer("unwrap"):
        windows = _windows(camera, views, radius, mm, settings, occluded)
    window = windows[1]
    # Registration strips get FFT-friendly sizes; the canvas keeps square pixels.
    fine = WallGrid.window(radius, mm * settings.final_coarsening,
                            *windows[settings.final_coarsening], fft_sizes=True)
    coarse = WallGrid.window(radius, mm * settings.register_coarsening,
                              *windows[settings.register_coarsening], fft_sizes=True)
    unwrapper = _Unwrapper(camera, settings, radius, occluded, optical_centre_px(camera),
                           radial_edges(camera),
                           noise or _led_noise(dataset, sorted(usable), timer), defects)
    reg = _registration_rounds(dataset, views, unwrapper, (coarse, fine), settings.refine_rounds,
                               timer, show_progress, skipped)
    given = positions
    imu = read_imu(dataset.root) if given is None else None   # once: placed up to 4 times
    positions, placed = _placing(dataset, reg, given, skipped, timer, imu)
    walls = {i: v.profile for i, v in views.items() if v.profile is not None}
    # measured again only where refined: without the refinement, the walls serve the stitch
    measure = given is None and settings.refine_rounds > 0
    for _ in range(PROFILE_ROUNDS if measure else 1):
        reg, redone = _with_wall_profiles(dataset, reg, positions, unwrapper, fine, window,
                                          timer, skipped, again=measure, given=walls)
        if not redone:
            break
        before, (positions, placed) = positions.z_mm, _placing(dataset, reg, given, skipped,
                                                               timer, imu)
        if not np.any(np.abs(positions.z_mm[redone] - before[redone])
                      >= fine.mm_per_px_axial / 4):
            break   # the rings stand where the walls were placed: the profiles hold
    views, links = reg.views, reg.links
    canvas = Canvas(canvas_grid(positions.z_mm[placed], window,
                                WallGrid.window(radius, mm, *window)))
    release_free_memory()   # the stitch starts from what is live, not the passes' peak
    if sink is not None:
        sink.start(canvas.grid, radius)
    gains = _stitch(dataset, views, unwrapper, positions, placed, canvas, window,
                    reg.flat_field, timer, show_progress, skipped, sink)
    image, weights = canvas.image() if sink is None else (None, None)
    return MosaicResult(canvas.grid, image, weights, positions, links, radius, window,
                        [i for i in placed if i in gains], skipped, gains, reg.switched, views,
                        reg.chains, reg.led_share, reg.led_share_told)
