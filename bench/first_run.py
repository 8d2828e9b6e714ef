"""The first ``pipestitch run`` after set-up against a warm one, as the user runs it.

Every run is ``pipestitch run`` as a child process on the same dataset (``--scenario``,
default ``chart83``: 20 pairs at 1224 x 1024), each with numba's cache in a folder of
its own (``NUMBA_CACHE_DIR``), so nothing another process compiled is reused:

- ``cold``: an empty cache, the first run compiles every kernel (what the first run
  cost before set-up compiled them; left out by ``--quick``, as it takes a minute);
- ``set-up``: ``scripts/compile_kernels.py`` into a second empty cache, as
  ``scripts/setup-env.sh`` runs it after installing;
- ``first``: the first run on that cache;
- ``warm``: the runs after it (``--repeat``), with the cache and the files read by
  ``first`` in place.

Prints each wall time, pairs per second and peak resident memory (getrusage of the
child), the ratios to the fastest warm run, and the decode floor: the time to read
every frame of the dataset once on one thread (``cv2.imread``, in this process), taken
right after each warm run, and each warm run's ratio to the floor beside it (a shared
machine's speed drifts by tens of percent within minutes; the ratio of neighbours
moves less); then the run's own reader over the same frames (PNGs decoded by
:mod:`pipestitch.io.png`, faster than OpenCV; the floor stays OpenCV's). Targets:
``first`` <= 1.5 x ``warm``; a warm
run >= 10 pairs/s at 1224 x 1024 and <= 3 x the decode floor.

The simulator writes its frames with OpenCV: 8-bit grey PNGs, every row Sub-filtered.
``--frames`` saves the simulated frames again as others write them, the same pixels:
``pillow`` (Pillow's PNG writer, which imageio uses too: a filter chosen for each row,
mostly Paeth on a textured frame), ``colour`` (BGR, the grey value in each channel) or
``16bit`` (grey, times 257).

Run: python -u bench/first_run.py [--quick] [--pairs N] [--repeat N] [--work DIR]
                                  [--frames opencv|pillow|colour|16bit]
     python -u bench/first_run.py --dataset DIR [--no-cold]   (an existing dataset)
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMPILE = ROOT / "scripts" / "compile_kernels.py"


def pipestitch() -> list[str]:
    """The command line of the ``pipestitch`` console script of this interpreter.

    Returns
    -------
    list of str
        The script beside ``sys.executable``, else ``python -m pipestitch.cli``.
    """
    script = Path(sys.executable).with_name("pipestitch")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "pipestitch.cli"]


def timed(cmd: list[str], cache: Path) -> tuple[float, float]:
    """Run ``cmd`` as a child with numba's cache in ``cache``; its wall time and peak
    resident memory.

    Parameters
    ----------
    cmd : list of str
        Command line.
    cache : pathlib.Path
        ``NUMBA_CACHE_DIR`` of the child.

    Returns
    -------
    tuple of float
        Wall time (s) and peak resident memory (MB) of the child.
    """
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    with tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)   # this child's own rusage
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n"
                             f"{err.read().decode(errors='replace')[-2000:]}")
    return wall, usage.ru_maxrss / 1024


def decode_floor(data: Path, *, own: bool = False) -> float:
    """Seconds to decode every frame of ``data/frames`` once, on one thread, with
    ``cv2.imread`` (the floor the ratios are taken to), or with ``own`` the run's own
    reader (:func:`pipestitch.io.images.read_image`, PNGs by :mod:`pipestitch.io.png`)."""
    import cv2

    from pipestitch.io.images import read_image

    cv2.setNumThreads(1)
    paths = sorted((data / "frames").iterdir())
    if own:
        read_image(paths[0])   # its compiled unfilter loaded before the clock starts
    t0 = time.perf_counter()
    for path in paths:
        if own:
            read_image(path)
        elif cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is None:
            raise SystemExit(f"{path}: not an image")
    return time.perf_counter() - t0


FRAMES = ("opencv", "pillow", "colour", "16bit")   # how --frames saves the simulated frames


def rewrite_frames(data: Path, how: str) -> None:
    """Save every frame of ``data/frames`` again as ``how`` says (:data:`FRAMES`; the
    module docstring), the same pixels; "opencv" leaves them as they are."""
    if how not in FRAMES:
        raise ValueError(f"--frames: expected one of {', '.join(FRAMES)}, got {how!r}")
    if how == "opencv":
        return
    import cv2
    import numpy as np
    from PIL import Image  # installed with matplotlib

    for path in sorted((data / "frames").glob("*.png")):
        grey = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if how == "pillow":
            Image.fromarray(grey).save(path)
        elif how == "colour":
            cv2.imwrite(str(path), cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
        else:
            cv2.imwrite(str(path), grey.astype(np.uint16) * 257)


def main() -> None:
    """Simulate the dataset, time the runs, print the table and the ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="2 pairs, no cold run (smoke test)")
    parser.add_argument("--scenario", default="chart83")
    parser.add_argument("--size", default="half")
    parser.add_argument("--pairs", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=2, help="warm runs")
    parser.add_argument("--work", type=Path, help="keep the dataset, caches and outputs here")
    parser.add_argument("--dataset", type=Path, help="time this dataset (not simulated)")
    parser.add_argument("--no-cold", action="store_true", help="leave out the cold run")
    parser.add_argument("--frames", default="opencv", choices=FRAMES,
                        help="save the simulated frames again this way (the same pixels)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="pipestitch-first-run-"))
    work.mkdir(parents=True, exist_ok=True)
    data = args.dataset or work / "data"
    pairs = (len(list((data / "frames").glob("led_*"))) if args.dataset
             else 2 if args.quick else args.pairs)
    try:
        if not data.is_dir():
            subprocess.run([*pipestitch(), "simulate", "--scenario", args.scenario, "--size",
                            args.size, "--pairs", str(pairs), "--out", str(data), "-q"],
                           check=True, stdout=subprocess.DEVNULL)
            rewrite_frames(data, args.frames)
        run = [*pipestitch(), "run", str(data), "-q", "--out"]
        caches = {name: Path(tempfile.mkdtemp(prefix=f"numba-{name}-", dir=work))
                  for name in ("cold", "setup")}
        rows: list[tuple[str, float, float]] = []
        if not (args.quick or args.no_cold):
            rows.append(("cold (empty cache)", *timed([*run, str(work / "out-cold")],
                                                      caches["cold"])))
        rows.append(("set-up: compile_kernels.py",
                     *timed([sys.executable, str(COMPILE)], caches["setup"])))
        rows.append(("first run after set-up", *timed([*run, str(work / "out-first")],
                                                      caches["setup"])))
        floors = []   # the decode floor right after each warm run: the machine's speed drifts
        for k in range(max(1, args.repeat)):
            rows.append((f"warm run {k + 1}", *timed([*run, str(work / f"out-warm{k}")],
                                                     caches["setup"])))
            floors.append(decode_floor(data))
        warm = min(wall for name, wall, _ in rows if name.startswith("warm"))
        what = args.dataset or (f"{args.scenario!r} at {args.size} size"
                                + ("" if args.frames == "opencv" else f", {args.frames} frames"))
        print(f"pipestitch run, {pairs} pairs of {what}, {os.cpu_count()} cores")
        print(f"{'what':<28} {'wall s':>8} {'pairs/s':>8} {'peak MB':>8} {'x warm':>7}")
        for name, wall, mb in rows:
            rate = f"{pairs / wall:8.2f}" if "compile" not in name else f"{'':8}"
            print(f"{name:<28} {wall:8.2f} {rate} {mb:8.0f} {wall / warm:7.2f}")
        first = next(wall for name, wall, _ in rows if name.startswith("first"))
        print(f"first run / warm: {first / warm:.2f} (target <= 1.5)")
        walls = [wall for name, wall, _ in rows if name.startswith("warm")]
        ratios = [wall / floor for wall, floor in zip(walls, floors, strict=True)]
        print(f"decode floor (every frame once, one thread) after each warm run: "
              f"{', '.join(f'{f:.2f}' for f in floors)} s; warm run / decode: "
              f"{', '.join(f'{r:.2f}' for r in ratios)}, median {statistics.median(ratios):.2f} "
              f"(target <= 3)")
        own = decode_floor(data, own=True)
        print(f"the run's own reader over the same frames (one thread): {own:.2f} s, "
              f"{floors[-1] / own:.2f}x faster than cv2.imread")
        if not (args.quick or args.no_cold):
            cold = rows[0][1]
            print(f"cold run / warm: {cold / warm:.2f}; set-up compile + first run: "
                  f"{rows[1][1] + first:.1f} s against {cold:.1f} s cold")
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
