"""Mosaic quality and end-to-end throughput: ours vs no centralisation vs the polar baseline.

For each simulated dataset (a test chart in an 83 mm pipe with 20 pairs like the
reference experiment, a corroded pipe with an odometer, a feature-poor aluminium pipe
whose odometer slips), the whole ``pipestitch run`` pipeline is run three times in
one process on the same frames, changing only the unwrap:

* ours: centralised (each frame's pose from its laser ring);
* centred: our pipeline with the pose forced to a centred probe (no centralisation);
* polar: the prior-art polar unwrap about the image centre.

Beside them, the true-pose mosaic: the same unwrap, flat field and blend with each
frame's true pose (truth/poses.csv) and each frame placed at its true z and roll, at
our mosaic's scale, with no photometric refinement (the poses are true) and rounded
to 8 bits like the written mosaic: what the stitch makes of perfect poses and
positions.

Scores against the true wall (``pipestitch.simulate.evaluate``): SSIM, the SSIM of the
worst tenth of the run, and the local geometric error (RMS displacement of 64 x 64
patches in mm, after removing the global axial offset and roll). Then ours' axial scale
and local geometry against the true-pose mosaic itself: the two share the frames, their
noise and the blend, so what the patches measure between them is the geometry of our
poses and positions, without the scatter that a weak texture's noise gives each patch
against the true wall. Targets (chart):
SSIM >= 0.8, geometric RMS <= 0.3 mm; SSIM within 0.03 of the true-pose mosaic's and,
on a corroded wall, >= 0.93 in every tenth of the run. Reference design: SSIM 0.3502
(centralised), 0.3022 (uncentred).

Throughput: pairs per second end to end (decode included, 2 worker threads) at
1224 x 1024 and 2448 x 2048, the CPU time per pair, and the share of time per stage,
ours next to the polar baseline. Targets: >= 10 pairs/s at 1224 x 1024, >= 4 pairs/s
at 2448 x 2048.

Run: python bench/mosaic.py [--quick] [--keep DIR] [--only quality|throughput]
[--sizes half full] [--scenarios chart83 corrosion aluminium] [--pairs N]
[--quality-pairs N] [--pipe-mm D] [--slip-mm S] [--seeds N ...] [--modes ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

from pipestitch._runtime.threads import opencv_threads
from pipestitch.geometry import PipeSection, Pose, RadiusProfile, WallGrid
from pipestitch.io.dataset import TRUTH_POSE_COLUMNS, open_dataset, read_csv_columns
from pipestitch.io.images import read_image
from pipestitch.io.outputs import mosaic_from_uint8, mosaic_to_uint8
from pipestitch.mosaic.register import Positions
from pipestitch.pipeline.frame_cache import CachedLedFrames
from pipestitch.pipeline.run import RunSummary, run_dataset
from pipestitch.pipeline.simulating import simulate_dataset
from pipestitch.pipeline.stitching import FrameView, MosaicResult, MosaicSettings, build_mosaic
from pipestitch.simulate.evaluate import MosaicScore, WallImage, score_mosaic
from pipestitch.simulate.scenarios import SCENARIOS

MODES = ("ours", "centred", "polar")
TRUE_POSE = "true-pose"
QUALITY_SCENARIOS = ("chart83", "corrosion", "aluminium")
MORE_SCENARIOS = ("reducer",)   # on request (--scenarios)


def true_wall(dataset: Path) -> WallImage:
    """The simulated wall's albedo (truth/wall.png) on its grid."""
    meta = json.loads((dataset / "truth" / "wall.json").read_text())
    wall = read_image(dataset / "truth" / "wall.png").astype(np.float32) / 255
    return WallImage(image=wall, grid=WallGrid.from_json(meta, wall.shape[1]))


def written_mosaic(dataset: Path, summary: RunSummary) -> tuple[WallImage, float, float]:
    """The full-resolution mosaic a run wrote (8-bit, mosaic.ome.tif: run streams it) and
    the offsets (z mm, roll deg) that take it to true coordinates: the median offsets of
    its placed frames' positions from the truth's."""
    result = summary.mosaic
    truth = read_csv_columns(dataset / "truth" / "poses.csv", ("frame", "z_mm", "roll_deg"))
    placed = np.array(result.placed)
    z_off = float(np.median(truth["z_mm"][placed] - result.positions.z_mm[placed]))
    roll_off = float(np.median(truth["roll_deg"][placed] - result.positions.roll_deg[placed]))
    mosaic_meta = json.loads((summary.out / "mosaic.json").read_text())
    full = mosaic_meta["full_resolution"]
    with tifffile.TiffFile(summary.out / full["file"]) as tif:
        image = mosaic_from_uint8(tif.series[0].levels[0].asarray())
    grid = WallGrid.from_json(full, image.shape[1], radius_mm=mosaic_meta["radius_mm"])
    return WallImage(image=image, grid=grid), z_off, roll_off


def score(dataset: Path, summary: RunSummary, truth_wall: WallImage) -> MosaicScore:
    """Score the mosaic a run wrote against the true wall (:func:`written_mosaic`)."""
    image, z_off, roll_off = written_mosaic(dataset, summary)
    return score_mosaic(image, truth_wall, z_off, roll_off)


def true_views(dataset: Path) -> tuple[dict[int, FrameView], Positions]:
    """Every frame's view from the simulator's truth (pose without roll, the true
    section turned into the frame's roll-free axes) and the true z and roll."""
    truth = read_csv_columns(dataset / "truth" / "poses.csv", TRUTH_POSE_COLUMNS)
    simulation = json.loads((dataset / "truth" / "simulation.json").read_text())
    pipe, reducer = simulation["pipe"], simulation.get("diameter_profile")
    views = {}
    for k, frame in enumerate(truth["frame"].astype(int)):
        pose = Pose.from_degrees(*(float(truth[c][k]) for c in TRUTH_POSE_COLUMNS[1:5]))
        section = PipeSection(pipe["a_mm"], pipe["b_mm"],
                              float(np.deg2rad(pipe["angle_deg"] - truth["roll_deg"][k])))
        wall = None if reducer is None else RadiusProfile(
            np.array(reducer["z_mm"]) - truth["z_mm"][k],
            np.array(reducer["diameter_mm"]) / (2 * section.mean_radius_mm))
        views[int(frame)] = FrameView(pose, section, profile=wall)
    n = int(truth["frame"].max()) + 1
    z, roll = np.full(n, np.nan), np.full(n, np.nan)
    z[truth["frame"].astype(int)] = truth["z_mm"]
    roll[truth["frame"].astype(int)] = truth["roll_deg"]
    return views, Positions(z, roll, odometer_scale=1.0, outliers=[])


def true_pose_mosaic(dataset: Path, mm_per_px: float) -> MosaicResult:
    """The run stitched with the true poses and positions, at ``mm_per_px``."""
    views, positions = true_views(dataset)
    data = CachedLedFrames(open_dataset(dataset))
    settings = MosaicSettings(mm_per_px=mm_per_px, refine_iterations=0)
    try:
        with opencv_threads(1 if settings.workers > 1 else 0):
            return build_mosaic(data, views, settings, show_progress=False,
                                positions=positions)
    finally:
        data.close()


def true_pose_image(result: MosaicResult) -> WallImage:
    """The true-pose mosaic after the 8-bit rounding of a written mosaic; it lies in
    true coordinates."""
    return WallImage(image=mosaic_from_uint8(mosaic_to_uint8(result.image)[0]), grid=result.grid)


def score_true_pose(result: MosaicResult, truth_wall: WallImage) -> MosaicScore:
    """Score the true-pose mosaic (:func:`true_pose_image`: offsets 0, refined by the
    score as any mosaic's are)."""
    return score_mosaic(true_pose_image(result), truth_wall, 0.0, 0.0)


def tilt_error_deg(dataset: Path, out: Path) -> float:
    """Mean |error| of alpha and beta (deg) of the written poses against the truth."""
    cols = ("alpha_deg", "beta_deg")
    est = read_csv_columns(out / "poses.csv", cols)
    truth = read_csv_columns(dataset / "truth" / "poses.csv", cols)
    return float(np.nanmean(np.abs(np.column_stack([est[c] - truth[c] for c in cols]))))


def quality_row(name: str, label: str, s: MosaicScore, reference: MosaicScore,
                placed: str, tilt: str, rate: str) -> str:
    """One line of the quality table."""
    versus = f"{s.ssim - reference.ssim:+7.3f}" if label != TRUE_POSE else f"{'-':>7}"
    patches = f"{s.n_patches} ({s.n_rejected})"
    return (f"{name:>10} | {label:>9} | {s.ssim:6.3f} | {versus} | {s.ssim_worst_tenth:10.3f} | "
            f"{s.geometric_rms_mm:11.3f} | {100 * s.axial_scale_error:+10.3f}% | "
            f"{s.local_rms_mm:8.3f} | {s.shading_dn:7.2f} | {patches:>18} | {placed:>6} | "
            f"{tilt:>8} | {rate:>7}")


@dataclasses.dataclass(frozen=True)
class Variant:
    """How the quality datasets are made and run: the simulated LED exposure (None: the
    scenario's), the simulation's seed (wall, trajectory and noise) and the unwraps run
    beside the true-pose mosaic (``ours`` always)."""

    led_gain: float | None = None
    seed: int = 1
    modes: tuple[str, ...] = MODES
    pairs: int | None = None       # the run's pairs (None: the scenario's)
    pipe_mm: float | None = None   # the pipe's inner diameter (None: the scenario's)
    slip_mm: float = 0.0           # the odometer reads this much short from mid-run on

    def dataset(self, root: Path, name: str, size: str, pairs: int | None) -> Path:
        """The scenario's dataset in ``root``, simulated on first use."""
        pairs = pairs or self.pairs
        tags = (("" if self.led_gain is None else f"_gain{self.led_gain:g}")
                + ("" if self.seed == 1 else f"_seed{self.seed}")
                + ("" if pairs is None else f"_{pairs}pairs")
                + ("" if self.pipe_mm is None else f"_pipe{self.pipe_mm:g}")
                + ("" if not self.slip_mm else f"_slip{self.slip_mm:g}"))
        dataset = root / f"{name}_{size}{tags}"
        scenario = SCENARIOS[name]
        if self.led_gain is not None:
            scenario = dataclasses.replace(
                scenario, optics=dataclasses.replace(scenario.optics, led_gain=self.led_gain))
        if self.pipe_mm is not None:
            scenario = dataclasses.replace(scenario, pipe_diameter_mm=self.pipe_mm)
        if not (dataset / "probe.toml").exists():
            simulate_dataset(scenario, dataset, seed=self.seed, size=size, n_pairs=pairs,
                             show_progress=False)
            if self.slip_mm:
                slip_odometer(dataset, self.slip_mm)
        return dataset


def slip_odometer(dataset: Path, slip_mm: float) -> None:
    """A cable slip: the dataset's odometer reads ``slip_mm`` short from its middle frame
    on (odometry.csv rewritten; the truth is not touched)."""
    path = dataset / "odometry.csv"
    if not path.exists():
        raise ValueError(f"{dataset.name}: no odometer to slip")
    odo = read_csv_columns(path, ("frame", "z_mm"))
    frames = odo["frame"].astype(int)
    z = odo["z_mm"] - np.where(frames >= np.median(frames), slip_mm, 0.0)
    path.write_text("frame,z_mm\n" + "".join(f"{f},{v:.6f}\n" for f, v in zip(frames, z,
                                                                                 strict=True)))


def quality(root: Path, scenarios: list[str], size: str, pairs: int | None,
            variant: Variant = Variant()) -> dict[str, MosaicScore]:
    """Print the quality table of ``scenarios``; return ours' score per scenario."""
    gain = "" if variant.led_gain is None else f", LED frames exposed {variant.led_gain:g}x"
    gain += "" if variant.pairs is None else f", {variant.pairs} pairs"
    gain += "" if variant.pipe_mm is None else f", {variant.pipe_mm:g} mm pipe"
    gain += "" if not variant.slip_mm else f", odometer {variant.slip_mm:g} mm short from mid-run"
    print(f"\nMosaic quality ({size} size{gain}, seed {variant.seed}; reference design: "
          "SSIM 0.3502 centralised, 0.3022 uncentred)")
    print("(tilt err: mean |alpha, beta error| of poses.csv; ours = refined with the LED "
          "frames, the others = the ring alone)")
    print("(axial scale: mosaic z per true z - 1, in %; local: RMS after removing the "
          "offsets and that scale; shading: low-frequency brightness error, 8-bit levels)")
    print(f"({TRUE_POSE}: the same stitch with the true poses, z and roll, at ours' scale, "
          "8-bit; vs true: SSIM minus its SSIM, target within 0.03; worst 10th: the lowest "
          "SSIM of the run's ten axial tenths, target >= 0.93 on a corroded wall)")
    print(f"{'dataset':>10} | {'unwrap':>9} | {'SSIM':>6} | {'vs true':>7} | {'worst 10th':>10} | "
          f"{'geom RMS mm':>11} | {'axial scale':>11} | {'local mm':>8} | {'shading':>7} | "
          f"{'patches (rejected)':>18} | {'placed':>6} | {'tilt err':>8} | {'pairs/s':>7}")
    ours = {}
    for name in scenarios:
        dataset = variant.dataset(root, name, size, pairs)
        truth_wall = true_wall(dataset)
        runs = {}
        for mode in dict.fromkeys(("ours", *variant.modes)):
            out = root / f"out_{dataset.name}_{mode}"
            summary = run_dataset(dataset, out, settings=MosaicSettings(mode=mode),
                                  show_progress=False)
            runs[mode] = (summary, score(dataset, summary, truth_wall),
                          tilt_error_deg(dataset, out))
        mm_per_px = runs["ours"][0].mosaic.grid.mm_per_px_axial
        result = true_pose_mosaic(dataset, mm_per_px)
        reference = score_true_pose(result, truth_wall)
        for mode, (summary, s, tilt) in runs.items():
            print(quality_row(name, mode, s, reference,
                              f"{summary.n_placed:3d}/{summary.n_frames:<2d}", f"{tilt:7.3f}°",
                              f"{summary.pairs_per_second:7.2f}"), flush=True)
        n_frames = runs["ours"][0].n_frames
        print(quality_row(name, TRUE_POSE, reference, reference,
                          f"{len(result.placed):3d}/{n_frames:<2d}", "-", "-"), flush=True)
        for label, s in (("ours", runs["ours"][1]), (TRUE_POSE, reference)):
            print(f"{'':>10}   SSIM per tenth, {label:>9}: "
                  + " ".join(f"{v:.3f}" for v in s.ssim_tenths), flush=True)
        image, z_off, roll_off = written_mosaic(dataset, runs["ours"][0])
        against = score_mosaic(image, true_pose_image(result), z_off, roll_off)
        print(f"{'':>10}   ours against the {TRUE_POSE} mosaic: axial scale "
              f"{100 * against.axial_scale_error:+.3f} %, local {against.local_rms_mm:.3f} mm "
              f"({against.n_patches} patches)", flush=True)
        ours[name] = runs["ours"][1]
    return ours


def over_seeds(root: Path, scenarios: list[str], size: str, seeds: list[int],
               variant: Variant) -> None:
    """The quality table for each seed, then ours' axial scale error over the seeds: its
    mean is the bias, its spread what one run can tell of it."""
    scores = [quality(root, scenarios, size, None, dataclasses.replace(variant, seed=seed))
              for seed in seeds]
    print(f"\nAxial scale error of ours over seeds {seeds} ({size} size):")
    for name in scenarios:
        values = 100 * np.array([s[name].axial_scale_error for s in scores])
        spread = f", sd {values.std(ddof=1):.3f} %" if len(values) > 1 else ""
        print(f"{name:>10}: mean {values.mean():+.3f} %{spread}; "
              + " ".join(f"{v:+.3f}" for v in values), flush=True)


def warm_up(dataset: Path, out: Path) -> None:
    """One untimed run of each mode: numba compiles its kernels on their first call
    (or loads them from its cache), which is no part of the per-pair throughput."""
    start = time.perf_counter()
    for mode in ("ours", "polar"):
        run_dataset(dataset, out / f"out_warm_up_{mode}", settings=MosaicSettings(mode=mode),
                    show_progress=False)
    print(f"(warm-up runs first, not timed: {time.perf_counter() - start:.1f} s, JIT compile "
          "or cache load included)", flush=True)


def throughput(root: Path, sizes: list[str], pairs: int) -> None:
    print("\nThroughput end to end (decode included, 2 threads)")
    datasets = {size: root / f"throughput_{size}_{pairs}" for size in sizes}
    for size, dataset in datasets.items():
        if not (dataset / "probe.toml").exists():
            simulate_dataset(SCENARIOS["corrosion"], dataset, seed=2, size=size, n_pairs=pairs,
                             show_progress=False)
    warm_up(datasets[sizes[0]], root)
    print("(CPU ms/pair: CPU time of the process, all threads, over the whole run_dataset "
          "call (report included) per pair; the targets need <= ~200 and <= ~500 on 2 cores)")
    print(f"{'size':>9} | {'ours pairs/s':>12} | {'polar pairs/s':>13} | {'ratio':>5} | "
          f"{'CPU ms/pair ours, polar':>23} | share of time per stage (ours)")
    for size, dataset in datasets.items():
        runs, cpu = {}, {}
        for mode in ("ours", "polar"):
            start = time.process_time()
            runs[mode] = run_dataset(dataset, root / f"out_throughput_{size}_{mode}",
                                     settings=MosaicSettings(mode=mode), show_progress=False)
            cpu[mode] = 1000 * (time.process_time() - start) / max(runs[mode].n_frames, 1)
        ours, polar = runs["ours"], runs["polar"]
        total = sum(ours.stage_seconds.values())
        shares = ", ".join(f"{k} {100 * v / total:.0f}%" for k, v in
                           sorted(ours.stage_seconds.items(), key=lambda kv: -kv[1]))
        label = "1224x1024" if size == "half" else "2448x2048"
        cpus = f"{cpu['ours']:.0f}, {cpu['polar']:.0f}"
        print(f"{label:>9} | {ours.pairs_per_second:12.2f} | {polar.pairs_per_second:13.2f} | "
              f"{ours.pairs_per_second / polar.pairs_per_second:5.2f} | {cpus:>23} | {shares}",
              flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="smoke run (CI): half size, chart only, 4 pairs")
    parser.add_argument("--keep", type=Path, help="keep datasets and outputs in this folder")
    parser.add_argument("--only", choices=("quality", "throughput"),
                        help="run one part of the benchmark only")
    parser.add_argument("--sizes", nargs="+", choices=("half", "full"), default=["half", "full"],
                        help="frame sizes (default both; the full-size quality table is "
                             "chart83's)")
    parser.add_argument("--scenarios", nargs="+", choices=QUALITY_SCENARIOS + MORE_SCENARIOS,
                        default=list(QUALITY_SCENARIOS),
                        help="datasets of the quality part (default chart83, corrosion, "
                             "aluminium; reducer on request)")
    parser.add_argument("--full-scenarios", nargs="+", choices=QUALITY_SCENARIOS,
                        default=["chart83"],
                        help="datasets of the full-size quality table (default chart83)")
    parser.add_argument("--led-gain", type=float,
                        help="exposure of the simulated LED frames instead of the scenario's "
                             "(1.8: the chart's lit wall is clipped in most frames; 0.9: not)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1],
                        help="simulation seeds of the quality datasets (default 1); with "
                             "several, ours' axial scale error over them")
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES),
                        help="unwraps of the quality table besides the true-pose mosaic "
                             "(default all; ours always)")
    parser.add_argument("--pairs", type=int, default=30,
                        help="pairs of the throughput dataset (default 30)")
    parser.add_argument("--quality-pairs", type=int,
                        help="pairs of the quality datasets (default: each scenario's)")
    parser.add_argument("--pipe-mm", type=float,
                        help="inner diameter of the quality datasets' pipe (default: each "
                             "scenario's)")
    parser.add_argument("--slip-mm", type=float, default=0.0,
                        help="the quality datasets' odometer reads this much short from "
                             "their middle frame on (a cable slip; default none)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="pipestitch-bench-") as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        if args.quick:
            quality(root, ["chart83"], "half", 4)
            throughput(root, ["half"], 4)
            return
        if args.only != "throughput":
            variant = Variant(args.led_gain, modes=tuple(args.modes),
                              pairs=args.quality_pairs, pipe_mm=args.pipe_mm,
                              slip_mm=args.slip_mm)
            if "half" in args.sizes:
                over_seeds(root, args.scenarios, "half", args.seeds, variant)
            full = [name for name in args.full_scenarios if name in args.scenarios]
            if "full" in args.sizes and full:
                over_seeds(root, full, "full", args.seeds, variant)
        if args.only != "quality":
            throughput(root, args.sizes, args.pairs)


if __name__ == "__main__":
    main()
