"""Writing a simulated dataset to disk exactly per SPEC.

Layout: probe.toml, frames/laser_NNNNN.png and led_NNNNN.png, odometry.csv when
the scenario has an odometer, and truth/ (poses.csv, wall.png, wall.json,
defects.csv, simulation.json with the optics and seed).
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
from pathlib import Path

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.geometry import Pose
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.dataset import TRUTH_POSE_COLUMNS
from pipestitch.io.images import write_image
from pipestitch.io.probe_toml import probe_config_for, read_probe_toml, write_probe_toml
from pipestitch.pipeline.progress import track
from pipestitch.simulate.scenarios import PLANE_DISTANCE_MM, Scenario, SyntheticRun, build_run

__all__ = ["simulate_dataset", "simulated_before", "write_truth"]


def _csv(header: list[str], rows: list[list[object]]) -> str:
    def fmt(v: object) -> str:
        return f"{v:.6f}" if isinstance(v, float) else str(v)

    return "\n".join([",".join(header), *(",".join(fmt(v) for v in r) for r in rows)]) + "\n"


def write_truth(run: SyntheticRun, out: Path) -> None:
    """Write truth/ (poses, wall, defects, simulation parameters)."""
    truth = out / "truth"
    atomic_write_text(truth / "poses.csv", _pose_rows(run.poses))
    if run.led_poses is not None:   # the LED frames' own (not in SPEC: readers skip it)
        atomic_write_text(truth / "led_poses.csv", _pose_rows(run.led_poses))
    write_image(truth / "wall.png", np.clip(np.rint(run.albedo * 255), 0, 255).astype(np.uint8))
    atomic_write_text(truth / "wall.json", json.dumps(run.grid.to_json(), indent=2))
    atomic_write_text(truth / "defects.csv", _csv(
        ["kind", "z_mm", "theta_deg", "diameter_mm"],
        [[d.kind, float(d.z_mm), float(d.theta_deg), float(d.diameter_mm)] for d in run.defects]))
    sim = {
        "scenario": run.scenario.name, "seed": run.seed,
        "optics": dataclasses.asdict(run.scenario.optics),
        "pipe": {"a_mm": run.section.a_mm, "b_mm": run.section.b_mm,
                 "angle_deg": float(np.rad2deg(run.section.angle))},
        "body": dataclasses.asdict(run.body),
    }
    if run.scenario.led_share != 0:
        sim["led_share"] = run.scenario.led_share
    if run.profile is not None:   # the wall's mean diameter along world z (a reducer)
        sim["diameter_profile"] = {
            "z_mm": run.profile.z_mm.tolist(),
            "diameter_mm": (2 * run.section.mean_radius_mm * run.profile.scale).tolist()}
    atomic_write_text(truth / "simulation.json", json.dumps(sim, indent=2))


def _pose_rows(poses: list[Pose]) -> str:
    """truth/poses.csv's text for ``poses`` (frame i is poses[i])."""
    rows = []
    for i, pose in enumerate(poses):
        d = pose.as_degrees()
        rows.append([i, d["alpha_deg"], d["beta_deg"], d["dx_mm"], d["dy_mm"], d["z_mm"],
                     d["roll_deg"]])
    return _csv(list(TRUTH_POSE_COLUMNS), rows)


_RUN: tuple[SyntheticRun, Path] | None = None    # a rendering worker's run (inherited by fork)


def _write_pair(i: int) -> int:
    """Render pair ``i`` of the worker's run and write its frames."""
    assert _RUN is not None
    run, frames_dir = _RUN
    if run.scenario.laser_only:
        write_image(frames_dir / f"laser_{i:05d}.png", run.render_laser(i))
    else:
        laser, led = run.render(i)
        write_image(frames_dir / f"laser_{i:05d}.png", laser)
        write_image(frames_dir / f"led_{i:05d}.png", led)
    return i


def _render_all(run: SyntheticRun, frames_dir: Path, workers: int, show_progress: bool) -> None:
    """Every pair, in ``workers`` forked processes that share the run's wall texture.

    Pair i's noise comes from its own generator (seed, i): the frames do not depend
    on the order or the number of workers.
    """
    global _RUN
    _RUN = (run, frames_dir)
    n = len(run.poses)
    label = f"simulating {run.scenario.name}"
    try:
        if workers <= 1 or n < 2 or "fork" not in multiprocessing.get_all_start_methods():
            for _ in track(map(_write_pair, range(n)), label, total=n, enabled=show_progress):
                pass
            return
        with multiprocessing.get_context("fork").Pool(min(workers, n)) as pool:
            done = pool.imap_unordered(_write_pair, range(n), chunksize=4)
            for _ in track(done, label, total=n, enabled=show_progress):
                pass
    finally:
        _RUN = None


def simulate_dataset(scenario: Scenario, out: str | Path, *, seed: int = 0, size: str = "full",
                     n_pairs: int | None = None, show_progress: bool = True,
                     workers: int = 1) -> SyntheticRun:
    """Simulate ``scenario`` and write it as a dataset folder ``out``.

    ``workers`` > 1 renders the pairs in that many forked processes (same frames).

    Returns
    -------
    SyntheticRun
        The in-memory run (poses, wall, renderer) the dataset was made from.
    """
    out = Path(out)
    frames_dir = out / "frames"
    if frames_dir.is_dir() and any(frames_dir.iterdir()):
        # Old frames of a longer run would silently contradict the new truth/.
        raise DatasetError(frames_dir, "already holds frames; simulate into an empty folder")
    run = build_run(scenario, seed=seed, size=size, n_pairs=n_pairs)
    cfg = probe_config_for(run.camera, plane_distance_mm=PLANE_DISTANCE_MM,
                           pipe_diameter_mm=scenario.pipe_diameter_mm,
                           **({"length_mm": run.body.length_mm, "diameter_mm": run.body.diameter_mm}
                              if scenario.declare_body else {}))
    write_probe_toml(out / "probe.toml", cfg)
    _render_all(run, frames_dir, workers, show_progress)
    if run.odometry_mm is not None:
        atomic_write_text(out / "odometry.csv", _csv(
            ["frame", "z_mm"], [[i, float(z)] for i, z in enumerate(run.odometry_mm)]))
    write_truth(run, out)
    return run


def simulated_before(dataset: Path, scenario: str, seed: int, size: str) -> bool:
    """True when ``dataset`` holds what :func:`simulate_dataset` makes of ``scenario`` at
    ``seed`` and ``size`` (its truth/simulation.json and frame size say so): `demo --out
    DIR` run again processes it again instead of refusing the folder."""
    from pipestitch.camera import default_camera
    from pipestitch.errors import PipestitchError

    try:
        made = json.loads((dataset / "truth" / "simulation.json").read_text(encoding="utf-8"))
        width = read_probe_toml(dataset / "probe.toml").camera.width
    except (OSError, ValueError, PipestitchError):
        return False
    return (isinstance(made, dict) and made.get("scenario") == scenario
            and made.get("seed") == seed and width == default_camera(size).width)
