"""Long inspections at scale: memory and throughput vs run length, video vs frames,
the tiled pyramid writer, and batch on a local dask cluster vs sequential.

1. Runs of N pairs (default 250 and 1000; 4000 with ``--pairs 250 1000 4000``, which
   takes hours on a 2-core machine) of the ``default`` scenario at 1224 x 1024
   (``--size half``), written as frames and as a lossless FFVHuff video: each
   ``pipestitch run`` is a fresh child process that reports its peak resident memory
   (getrusage ru_maxrss) and pairs per second. ``nocache`` runs the frames with the
   LED frame cache off (``run`` keeps a short run's decoded LED frames, which makes
   the short run the larger one: without it the growth with the run's length shows).
   Targets (issue 8): memory at the longest run within 10 % of the shortest;
   throughput within 10 % of the single-run figure.
2. Pyramid writer: a synthetic mosaic of ``--mosaic-mpx`` megapixels written as a
   pyramidal OME-TIFF by ``io.tiles.write_pyramid`` from column blocks vs the baseline
   of tifffile writing the whole image (all levels computed in memory); peak memory
   and time, each in a child process.
3. Batch: ``--batch`` small datasets (``--batch-pairs`` pairs each) run one after the
   other in one process (``run`` with its default 2 threads) vs ``run_batch`` on a
   local cluster of ``--workers`` single-threaded processes: wall time and ratio
   (cluster start-up included).

Run: python -u bench/scale.py [--quick] [--pairs N ...] [--work DIR]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve()


def peak_rss_mb() -> float:
    """This process's peak resident memory (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _status_mb(key: str) -> float:
    """VmRSS / VmHWM (current / peak resident memory) of this process from /proc, MB
    (without /proc: the peak from getrusage for both)."""
    try:
        with open("/proc/self/status", encoding="ascii") as handle:
            for line in handle:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return peak_rss_mb()


def reset_peak_rss() -> float:
    """Reset this process's peak resident memory to the current one; returns it, MB.

    Linux: writing 5 to /proc/self/clear_refs resets VmHWM. So a child measures what
    its work adds, not the transient peak of its imports."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as handle:
            handle.write("5")
    except OSError:
        pass   # then VmHWM includes the imports, as ru_maxrss does
    return _status_mb("VmRSS")


def child(*args: str) -> dict:
    """Run this script in a fresh process with ``args``; its last stdout line is JSON."""
    proc = subprocess.run([sys.executable, "-u", str(SCRIPT), *args], capture_output=True,
                          text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"child {args} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


# --- child modes -------------------------------------------------------------------------

# The passes of a run whose peak resident memory is reported (module, class or "",
# function): the pose stage, the registration passes and their refinement, the
# stitch, the outputs.
PASSES = (("pipestitch.pipeline.run", "", "estimate_poses"),
          ("pipestitch.pipeline.stitching", "", "sample_led"),
          ("pipestitch.pipeline.stitching", "", "_register"),
          ("pipestitch.pipeline.stitching", "", "_refine_views"),
          ("pipestitch.pipeline.stitching", "", "_repatch"),
          ("pipestitch.pipeline.stitching", "", "_stitch"),
          ("pipestitch.pipeline.stitched_output", "StreamedMosaic", "finish"),
          ("pipestitch.pipeline.run", "", "_write_mosaic"),
          ("pipestitch.pipeline.run", "", "_coded"),
          ("pipestitch.pipeline.run", "", "render_report"))


class PassMemory:
    """Peak resident memory per pass of a run (``name#k``: its k-th call), sampled every
    20 ms from /proc/self/statm by a thread while the wrapped passes say which runs."""

    def __init__(self) -> None:
        import os
        import threading

        self.page = os.sysconf("SC_PAGE_SIZE")
        self.current, self.peak_mb, self.calls = ["other"], {}, {}
        for module, cls, name in PASSES:
            owner = importlib.import_module(module)
            owner = getattr(owner, cls) if cls else owner
            if hasattr(owner, name):
                setattr(owner, name, self._wrapped(getattr(owner, name), name))
        threading.Thread(target=self._sample, daemon=True).start()

    def _sample(self) -> None:
        while True:
            stage = self.current[-1]
            with open("/proc/self/statm") as f:
                rss = int(f.read().split()[1]) * self.page / 2**20
            self.peak_mb[stage] = max(rss, self.peak_mb.get(stage, 0.0))
            time.sleep(0.02)

    def _wrapped(self, func: Callable, name: str) -> Callable:
        @functools.wraps(func)
        def run(*args: object, **kwargs: object) -> object:
            self.calls[name] = self.calls.get(name, 0) + 1
            self.current.append(f"{name}#{self.calls[name]}")
            try:
                return func(*args, **kwargs)
            finally:
                self.current.pop()
        return run


def child_run(root: str, out: str, video: str | None, threads: int,
              led_cache_mb: float | None) -> dict:
    from pipestitch.pipeline.run import run_dataset
    from pipestitch.pipeline.stitching import MosaicSettings

    passes = PassMemory()
    start = time.perf_counter()
    cache = {} if led_cache_mb is None else {"led_cache_mb": led_cache_mb}
    summary = run_dataset(root, out, settings=MosaicSettings(workers=threads),
                          show_progress=False, video=Path(video) if video else None, **cache)
    seconds = time.perf_counter() - start
    return {"pairs": summary.n_frames, "placed": summary.n_placed, "seconds": seconds,
            "rss_mb": peak_rss_mb(), "pass_rss_mb": passes.peak_mb}


def _synthetic_column(rows: int, col0: int, width: int) -> np.ndarray:
    rng = np.random.default_rng(col0)
    return rng.integers(1, 256, (rows, width), dtype=np.uint8)


def child_pyramid(path: str, rows: int, cols: int, whole: bool) -> dict:
    import tifffile

    from pipestitch.io.tiles import level_shapes, write_pyramid

    base_mb = reset_peak_rss()
    start = time.perf_counter()
    blocks = ((c, _synthetic_column(rows, c, min(512, cols - c))) for c in range(0, cols, 512))
    if not whole:
        write_pyramid(path, blocks, (rows, cols), tiles_dir=Path(path).parent / "tiles")
    else:  # baseline: the image and every level in memory, then one tifffile call each
        import cv2

        image = np.concatenate([b for _, b in blocks], axis=1)
        n = next(k for k, s in enumerate(level_shapes(rows, cols)) if max(s) <= 256) + 1
        with tifffile.TiffWriter(path, bigtiff=True, ome=True) as tif:
            tif.write(image, tile=(256, 256), subifds=n - 1, compression="zlib")
            level = image
            for _ in range(n - 1):
                level = cv2.resize(level, ((level.shape[1] + 1) // 2, (level.shape[0] + 1) // 2),
                                   interpolation=cv2.INTER_AREA)
                tif.write(level, tile=(256, 256), subfiletype=1, compression="zlib")
    return {"seconds": time.perf_counter() - start, "rss_mb": _status_mb("VmHWM"),
            "import_mb": base_mb}


def child_batch(roots: list[str], out: str, mode: str, workers: int) -> dict:
    from pipestitch.pipeline.batch import run_batch
    from pipestitch.pipeline.run import run_dataset

    start = time.perf_counter()
    if mode == "sequential":
        ok = sum(not run_dataset(r, Path(out) / Path(r).name, show_progress=False).mosaic_failed
                 for r in roots)
    else:
        ok = sum(r.status == "ok" for r in run_batch(roots, out, workers=workers))
    return {"seconds": time.perf_counter() - start, "ok": ok}


# --- driver ------------------------------------------------------------------------------

def simulate(root: Path, pairs: int, size: str, seed: int) -> Path:
    if not (root / "probe.toml").is_file():
        subprocess.run([sys.executable, "-m", "pipestitch.cli.app", "simulate", "--scenario",
                        "default", "--size", size, "--pairs", str(pairs), "--seed", str(seed),
                        "--out", str(root), "--quiet", "--workers", "2"], check=True,
                       capture_output=True)
    return root


def prefix_run(longer: Path, root: Path, pairs: int) -> Path:
    """The first ``pairs`` pairs of a longer simulated run as a dataset of their own
    (frames linked, odometer cut): a shorter run of the same pipe, without simulating
    it again (a 4000-pair run takes about an hour to render on 2 cores)."""
    if not (root / "probe.toml").is_file():
        (root / "frames").mkdir(parents=True, exist_ok=True)
        for i in range(pairs):
            for kind in ("laser", "led"):
                name = f"{kind}_{i:05d}.png"
                (root / "frames" / name).symlink_to(longer / "frames" / name)
        odometry = longer / "odometry.csv"
        if odometry.is_file():
            lines = odometry.read_text().splitlines()
            (root / "odometry.csv").write_text("\n".join(lines[:pairs + 1]) + "\n")
        (root / "probe.toml").write_text((longer / "probe.toml").read_text())
    return root


def to_video(root: Path, path: Path) -> Path:
    from pipestitch.io.dataset import open_dataset
    from pipestitch.io.video import write_video

    if not path.is_file():
        ds = open_dataset(root)
        write_video(path, (f for i in range(ds.n_pairs) for f in (ds.read_laser(i),
                                                                  ds.read_led(i))))
    return path


def bench_runs(work: Path, pairs: list[int], size: str, threads: int,
               inputs: list[str], prefixes: bool) -> None:
    print(f"\n## runs of N pairs ({size} size frames, scenario default, {threads} threads)")
    print(f"{'pairs':>6} {'input':>7} {'seconds':>8} {'pairs/s':>8} {'peak RSS MB':>12}")
    rows = []
    longest = max(pairs)
    for n in pairs:
        if prefixes and n != longest:
            root = prefix_run(simulate(work / f"run{longest}", longest, size, seed=longest),
                              work / f"run{longest}_first{n}", n)
        else:
            root = simulate(work / f"run{n}", n, size, seed=n)
        video = to_video(root, work / f"run{n}.avi") if "video" in inputs else None
        # "nocache": frames with the LED frames' memory cache off, so the run reads them
        # back from its spill file as a run too long for the cache does (a short run is
        # otherwise cached whole, which makes it the larger one)
        for kind in inputs:
            args = ["--child-run", str(root), str(work / f"out{n}_{kind}"), str(threads)]
            args += ["--video", str(video)] if kind == "video" else []
            args += ["--led-cache-mb", "0"] if kind == "nocache" else []
            got = child(*args)
            rate = got["pairs"] / got["seconds"]
            rows.append((n, kind, rate, got["rss_mb"]))
            print(f"{n:>6} {kind:>7} {got['seconds']:>8.1f} {rate:>8.2f} {got['rss_mb']:>12.0f}",
                  flush=True)
            top = sorted(got["pass_rss_mb"].items(), key=lambda kv: -kv[1])[:4]
            print("       peak RSS by pass (MB): "
                  + ", ".join(f"{name} {mb:.0f}" for name, mb in top), flush=True)
    for kind in inputs:
        mine = sorted((r for r in rows if r[1] == kind), key=lambda r: r[0])
        first, last = mine[0], mine[-1]      # shortest and longest run
        print(f"{kind}: memory {last[0]} vs {first[0]} pairs: ratio {last[3] / first[3]:.2f} "
              f"(target <= 1.10); pairs/s ratio {last[2] / first[2]:.2f} (target >= 0.90)")


def bench_pyramid(work: Path, mpx: float) -> None:
    rows = 1536
    cols = int(mpx * 1e6 / rows)
    print(f"\n## pyramid writer: {rows} x {cols} mosaic ({rows * cols / 1e6:.0f} Mpx, 8-bit)")
    for name in ("base", "ours"):
        (work / name).mkdir(exist_ok=True)
    base = child("--child-pyramid", str(work / "base" / "m.ome.tif"), str(rows), str(cols),
                 "whole")
    ours = child("--child-pyramid", str(work / "ours" / "m.ome.tif"), str(rows), str(cols),
                 "stream")
    for label, r in (("baseline (whole image in memory, tifffile)", base),
                     ("ours (write_pyramid from 512-column blocks, + Deep Zoom tiles)", ours)):
        r["added_mb"] = r["rss_mb"] - r["import_mb"]
        print(f"{label}: {r['seconds']:.1f} s, peak RSS {r['rss_mb']:.0f} MB while writing, "
              f"{r['added_mb']:.0f} MB above the {r['import_mb']:.0f} MB after the imports")
    print(f"memory the writing adds, ours/baseline {ours['added_mb'] / base['added_mb']:.2f}, "
          f"time ratio {ours['seconds'] / base['seconds']:.2f}")


def bench_batch(work: Path, n: int, pairs: int, size: str, workers: int) -> None:
    print(f"\n## batch of {n} datasets x {pairs} pairs ({size} size)")
    roots = [str(simulate(work / f"batch{k}", pairs, size, seed=100 + k)) for k in range(n)]
    seq = child("--child-batch", "sequential", str(work / "seq"), str(workers), *roots)
    dask = child("--child-batch", "cluster", str(work / "cluster"), str(workers), *roots)
    print(f"sequential (one process, run with 2 threads): {seq['seconds']:.1f} s, "
          f"{seq['ok']}/{n} ok")
    print(f"local dask cluster ({workers} processes x 1 thread): {dask['seconds']:.1f} s, "
          f"{dask['ok']}/{n} ok")
    print(f"speed ratio cluster vs sequential: {seq['seconds'] / dask['seconds']:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    parser.add_argument("--pairs", type=int, nargs="+", default=[250, 1000])
    parser.add_argument("--size", default="half")
    parser.add_argument("--threads", type=int, default=2, help="threads of each run")
    parser.add_argument("--inputs", nargs="+", default=["frames", "nocache", "video"],
                        choices=["frames", "nocache", "video"])
    parser.add_argument("--prefixes", action="store_true",
                        help="shorter runs are the first pairs of the longest (one simulation)")
    parser.add_argument("--mosaic-mpx", type=float, default=60.0)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--batch-pairs", type=int, default=6)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip", nargs="*", default=[], choices=["runs", "pyramid", "batch"])
    parser.add_argument("--work", type=Path, help="keep the datasets and outputs here")
    parser.add_argument("--child-run", nargs=3)
    parser.add_argument("--video")
    parser.add_argument("--led-cache-mb", type=float,
                        help="LED frame cache budget of the runs (default: run's own)")
    parser.add_argument("--child-pyramid", nargs=4)
    parser.add_argument("--child-batch", nargs="+")
    args = parser.parse_args()
    if args.child_run:
        root, out, threads = args.child_run
        print(json.dumps(child_run(root, out, args.video, int(threads), args.led_cache_mb)))
        return
    if args.child_pyramid:
        path, rows, cols, mode = args.child_pyramid
        print(json.dumps(child_pyramid(path, int(rows), int(cols), mode == "whole")))
        return
    if args.child_batch:
        mode, out, workers, *roots = args.child_batch
        print(json.dumps(child_batch(roots, out, mode, int(workers))))
        return
    if args.quick:
        args.pairs, args.mosaic_mpx, args.batch, args.batch_pairs = [2], 1.0, 2, 2
    with tempfile.TemporaryDirectory(prefix="pipestitch-scale-") as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if "runs" not in args.skip:
            bench_runs(work, args.pairs, args.size, args.threads, args.inputs, args.prefixes)
        if "pyramid" not in args.skip:
            bench_pyramid(work, args.mosaic_mpx)
        if "batch" not in args.skip:
            bench_batch(work, args.batch, args.batch_pairs, args.size, args.workers)


if __name__ == "__main__":
    main()
