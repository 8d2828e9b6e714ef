"""Named simulation scenarios and the in-memory synthetic run they describe.

A :class:`Scenario` fixes the pipe, wall texture, defects, trajectory, optics and
odometer; :func:`build_run` turns it (with a seed and a sensor size) into a
:class:`SyntheticRun`: camera, poses, wall texture, renderer and truth tables.
Writing a dataset to disk is the pipeline's job (``pipeline/simulating.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from pipestitch.simulate.optics import Optics

if TYPE_CHECKING:   # the renderer and textures load when a run is built, not to list these
    from pipestitch.camera import CameraModel
    from pipestitch.geometry import BodyEnvelope, PipeSection, Pose, RadiusProfile, WallGrid
    from pipestitch.simulate.render import Renderer
    from pipestitch.simulate.textures import Defect

__all__ = ["SCENARIOS", "Scenario", "SyntheticRun", "build_run", "led_share_problem"]

PLANE_DISTANCE_MM = 16.0
REDUCER_LENGTH_MM = 20.0


@dataclass(frozen=True)
class Scenario:
    """Everything that defines a synthetic run except the seed and sensor size."""

    name: str
    description: str
    pipe_diameter_mm: float = 65.0
    n_pairs: int = 12
    texture: str = "corrosion"
    defects: str = "none"             # "none" | "test_piece" | "random"
    ovality: float = 0.0              # (Dmax - Dmin) / Dmean
    trajectory: str = "wander"        # "wander" | "table1"
    step_mm: float = 5.0
    wander: float = 0.8
    odometer: bool = False
    odometer_slip_probability: float = 0.0
    laser_only: bool = False
    optics: Optics = field(default_factory=Optics)
    declare_body: bool = True         # write the probe body into probe.toml (table1: a point probe)
    reducer_mm: float = 0.0           # diameter change over REDUCER_LENGTH_MM (< 0: narrows)
    # the share of the step to the next pair by which each LED frame follows its laser
    # frame (< 0: precedes it), the probe moving on along its track between the two (a
    # camera alternating laser and LED frames at a steady rate: 0.5); 0: taken together
    led_share: float = 0.0


SCENARIOS: dict[str, Scenario] = {s.name: s for s in [
    Scenario("default", "short run along a corroded 65 mm pipe with a few holes and spots, "
             "odometer", n_pairs=12, defects="random", odometer=True),
    Scenario("chart83", "test chart in an 83 mm pipe, 20 pairs (the reference mosaic experiment)",
             pipe_diameter_mm=83.0, n_pairs=20, texture="chart"),
    Scenario("test_piece", "reference test piece: 65 mm aluminium pipe, 7 holes of 6 mm in a "
             "cross 24 mm apart, 32 pairs over 160 mm", n_pairs=32, texture="aluminium",
             defects="test_piece"),
    Scenario("corroded_piece", "the reference test piece's 7 holes of 6 mm in a corroded 65 mm "
             "pipe (dark pits and stains around them), 36 pairs", n_pairs=36,
             defects="test_piece"),
    Scenario("corrosion", "corroded 65 mm pipe, 30 pairs, odometer", n_pairs=30, odometer=True,
             defects="random"),
    Scenario("aluminium", "feature-poor brushed aluminium 65 mm pipe with an odometer that "
             "slips", n_pairs=30, texture="aluminium", odometer=True,
             odometer_slip_probability=0.1),
    Scenario("grey_arm", "the test piece seen past a dark grey laser-holder arm and mirror "
             "mount (22-40 DN, brighter outward)", n_pairs=32, texture="aluminium",
             defects="test_piece", optics=Optics(occluder_level=0.09)),
    Scenario("lit_arm", "the test piece seen past a metal arm and mirror mount lit by the "
             "LEDs, brighter than the far wall", n_pairs=32, texture="aluminium",
             defects="test_piece", optics=Optics(occluder_level=0.45)),
    Scenario("auto_exposure", "corroded 65 mm pipe seen by a camera whose exposure steps "
             "by 25 % every 8 pairs, odometer", n_pairs=30, odometer=True, defects="random",
             optics=Optics(exposure_step=0.25)),
    Scenario("oval", "oval 65 mm pipe (ovality 5 %), corrosion texture", n_pairs=20,
             ovality=0.05, defects="random"),
    Scenario("reducer", "concentric reducer: a corroded 65 mm pipe narrowing to 61 mm over "
             "20 mm mid-run, 16 pairs, odometer", n_pairs=16, odometer=True, defects="random",
             reducer_mm=-4.0),
    Scenario("hard", "16-bit colour frames, glints, partial rings, strong noise",
             n_pairs=12, defects="random",
             optics=Optics(bit_depth=16, colour=True, glints=3, partial_ring_deg=60.0,
                           full_well_e=3000.0, read_noise=3.0 / 255, laser_peak=0.35)),
    *[Scenario(f"table1_{d}", f"reference evaluation: 300 independent random poses in a {d} mm "
               "pipe, laser frames only", pipe_diameter_mm=float(d), n_pairs=300,
               texture="aluminium", trajectory="table1", laser_only=True, declare_body=False)
      for d in (50, 65, 80)],
]}
SCENARIOS["table1"] = replace(SCENARIOS["table1_65"], name="table1")


@dataclass
class SyntheticRun:
    """A simulated run held in memory: render frames with :meth:`render`."""

    scenario: Scenario
    camera: CameraModel
    section: PipeSection
    body: BodyEnvelope
    poses: list[Pose]
    grid: WallGrid
    albedo: np.ndarray
    defects: list[Defect]
    odometry_mm: np.ndarray | None
    renderer: Renderer
    seed: int
    profile: RadiusProfile | None = None   # the wall's scale along z (a reducer)
    # the LED frames' poses where the probe moved between the two frames of a pair
    # (Scenario.led_share); None: each LED frame at its laser frame's pose
    led_poses: list[Pose] | None = None

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(laser, LED) frames of pair ``index`` (deterministic per seed and index)."""
        return self.renderer.render_pair(
            self.poses[index], self._rng(index), exposure=self.renderer.optics.exposure(index),
            led_pose=None if self.led_poses is None else self.led_poses[index])

    def render_laser(self, index: int) -> np.ndarray:
        """Laser frame of pair ``index`` only."""
        return self.renderer.render_laser(self.poses[index], self._rng(index))

    def _rng(self, index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, index])


def _random_defects(radius_mm: float, z0: float, z1: float,
                    rng: np.random.Generator) -> list[Defect]:
    """A few holes and spots spread over the run (not on its very ends)."""
    from pipestitch.simulate.textures import Defect

    out = []
    for kind, n in (("hole", 3), ("spot", 3)):
        for _ in range(n):
            out.append(Defect(kind, float(rng.uniform(z0, z1)), float(rng.uniform(0, 360)),
                              float(rng.uniform(3.0, 8.0))))
    return out


def led_share_problem(scenario: Scenario) -> str | None:
    """What is wrong with ``scenario.led_share`` (None: nothing)."""
    share = scenario.led_share
    if not -1.0 < share < 1.0:
        return f"led_share: expected between -1 and 1, got {share}"
    if share != 0 and (scenario.trajectory != "wander" or scenario.laser_only):
        return f"led_share: scenario {scenario.name!r} has no LED frames taken along a track"
    return None


def build_run(scenario: Scenario, *, seed: int = 0, size: str = "full",
              n_pairs: int | None = None) -> SyntheticRun:
    """Draw the trajectory, texture and defects of ``scenario`` and set up the renderer.

    Parameters
    ----------
    scenario : Scenario
        What to simulate.
    seed : int
        Random seed; the same seed gives the same dataset.
    size : {"full", "half"}
        Sensor size (2448 × 2048 or 1224 × 1024).
    n_pairs : int, optional
        Override the scenario's number of pairs.
    """
    from pipestitch.camera import default_camera
    from pipestitch.geometry import BodyEnvelope, PipeSection, WallGrid
    from pipestitch.simulate.render import Renderer, WallTexture
    from pipestitch.simulate.textures import make_wall, reference_test_piece
    from pipestitch.simulate.trajectory import WanderingTrack, odometer_readings, table1_poses

    if (problem := led_share_problem(scenario)) is not None:
        raise ValueError(problem)
    rng = np.random.default_rng(seed)
    n = scenario.n_pairs if n_pairs is None else int(n_pairs)
    if n < 1:
        raise ValueError(f"n_pairs: expected at least 1, got {n}")
    camera = default_camera(size)
    radius = scenario.pipe_diameter_mm / 2
    section = (PipeSection.oval(scenario.pipe_diameter_mm, scenario.ovality,
                                angle=float(rng.uniform(0, np.pi)))
               if scenario.ovality > 0 else PipeSection.circle(scenario.pipe_diameter_mm))
    body = BodyEnvelope()
    narrowing = min(1.0, 1.0 + scenario.reducer_mm / scenario.pipe_diameter_mm)
    led_poses = None
    if scenario.trajectory == "table1":
        # Independent poses at one axial position: z means nothing between them.
        poses = table1_poses(n, radius, PLANE_DISTANCE_MM, rng)
    else:
        narrowest = PipeSection(section.a_mm * narrowing, section.b_mm * narrowing,
                                section.angle)
        track = WanderingTrack(n, narrowest, body, rng, step_mm=scenario.step_mm,
                               wander=scenario.wander)
        poses = track.poses(track.z_mm)
        if scenario.led_share != 0:
            led_poses = track.poses(track.led_positions(scenario.led_share))
    z = np.array([p.z_mm for p in poses])
    profile = _reducer(scenario, float(np.median(z)) + PLANE_DISTANCE_MM)
    reach = 3.5 * max(section.a_mm, section.b_mm)
    mm_per_px = 0.04 if size == "full" else 0.07
    grid = WallGrid.square(radius, mm_per_px, float(z.min()) - 40.0, float(z.max()) + reach)
    defects: list[Defect] = []
    if scenario.defects == "test_piece":
        # Centred away from the laser holder arm (image azimuth 90°) for the middle frames.
        defects = reference_test_piece(float(np.mean(z)) + 40.0, theta_centre_deg=150.0,
                                       radius_mm=radius)
    elif scenario.defects == "random":
        defects = _random_defects(radius, float(z.min()) + 25, float(z.max()) + 45, rng)
    albedo = make_wall(scenario.texture, grid, rng=rng, defects=defects)
    odometry = (odometer_readings(z, rng, slip_probability=scenario.odometer_slip_probability)
                if scenario.odometer else None)
    wall = WallTexture(albedo=albedo, grid=grid)
    renderer = Renderer(camera, section, wall, PLANE_DISTANCE_MM, scenario.optics,
                        profile=profile)
    return SyntheticRun(scenario, camera, section, body, poses, grid, albedo, defects, odometry,
                        renderer, seed, profile, led_poses)


def _reducer(scenario: Scenario, middle_mm: float) -> RadiusProfile | None:
    """The scenario's reducer as a profile of the wall's scale, centred on ``middle_mm``
    (where the middle frame's ring is); None without one."""
    from pipestitch.geometry import RadiusProfile

    if scenario.reducer_mm == 0:
        return None
    start = middle_mm - REDUCER_LENGTH_MM / 2
    return RadiusProfile(np.array([start, start + REDUCER_LENGTH_MM]),
                         np.array([1.0, 1.0 + scenario.reducer_mm / scenario.pipe_diameter_mm]))
