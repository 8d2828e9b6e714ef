"""Simulator speed: one frame pair (laser + LED) at full and half size.

Baseline: the same ray tracing with a single bilinear lookup of the full-resolution
wall (no mip pyramid), i.e. what antialiasing costs. The issue's target is a full-size
pair in under 2 s.

Run: python bench/render.py [--quick]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pipestitch.simulate.scenarios import SCENARIOS, build_run


def time_pairs(run, n: int, *, antialias: bool) -> float:
    renderer = run.renderer
    pyramid = renderer._pyramid
    if not antialias:
        renderer._pyramid = pyramid[:1]
    try:
        start = time.perf_counter()
        for i in range(n):
            run.render(i % len(run.poses))
        return (time.perf_counter() - start) / n
    finally:
        renderer._pyramid = pyramid


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke run (CI): half size, 1 pair")
    args = parser.parse_args()
    sizes = ("half",) if args.quick else ("half", "full")
    n = 1 if args.quick else 5
    print(f"{'size':>5} | {'ours (mip)':>11} | {'baseline':>11} | {'ratio':>6} | pairs/s")
    for size in sizes:
        run = build_run(SCENARIOS["corrosion"], seed=0, size=size, n_pairs=max(n, 2))
        run.render(0)  # warm-up
        ours = time_pairs(run, n, antialias=True)
        base = time_pairs(run, n, antialias=False)
        print(f"{size:>5} | {ours:9.3f} s | {base:9.3f} s | {ours / base:5.2f}x | "
              f"{1 / ours:.2f} pairs/s")
    print(f"(mean of {n} pairs; ratio = ours / baseline; numpy {np.__version__})")


if __name__ == "__main__":
    main()
