"""How far the stated 1-sigma of the poses can be trusted: |error| / sigma against the
simulator's truth, ``pipestitch pose`` (the ring alone) and ``pipestitch run`` (poses
refined with the LED frames) side by side on the same simulated runs.

Per frame the largest |error| / sigma over alpha, beta, dx and dy (the chosen
hypothesis; errors against truth/poses.csv); per run its median and maximum over the
frames, and the median alpha sigma. For a sigma that says what it should, the median of
that largest ratio of four would be about 1.4 (0.67 for one Gaussian parameter); much
less is a sigma wider than the errors, above 3 a sigma narrower. The runs: simulator
scenarios, a corroded run taken every 2nd and 4th frame (10 and 20 mm steps: fewer
frames overlap, so the LED frames tell less), and its LED frames with noise of 15 % of
full scale added.

Each command runs as a subprocess, as a user runs it (accuracy, not speed: no timing).

Run: python bench/pose_sigma.py [--quick] [--size half|full]
"""

from __future__ import annotations

import argparse
import csv
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

POSE = ("alpha_deg", "beta_deg", "dx_mm", "dy_mm")
SIGMA = ("alpha_std_deg", "beta_std_deg", "dx_std_mm", "dy_std_mm")
# (name, scenario, pairs, every n-th pair, LED noise as a fraction of full scale)
RUNS = [
    ("corrosion", "corrosion", 60, 1, 0.0),
    ("corrosion, 10 mm steps", "corrosion", 60, 2, 0.0),
    ("corrosion, 20 mm steps", "corrosion", 60, 4, 0.0),
    ("corrosion, noisy LED frames", "corrosion", 20, 1, 0.15),
    ("reducer", "reducer", 16, 1, 0.0),
    ("oval", "oval", 20, 1, 0.0),
    ("hard", "hard", 12, 1, 0.0),
    ("aluminium", "aluminium", 10, 1, 0.0),
    ("chart83", "chart83", 10, 1, 0.0),
    ("lit_arm", "lit_arm", 10, 1, 0.0),
    ("auto_exposure", "auto_exposure", 10, 1, 0.0),
]
QUICK = [("corrosion", "corrosion", 6, 1, 0.0)]


def pipestitch(*args: str) -> None:
    """One ``pipestitch`` command as a subprocess; its output only on failure."""
    done = subprocess.run([sys.executable, "-m", "pipestitch.cli", *args, "--quiet"],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"pipestitch {' '.join(args)} failed:\n{done.stdout}{done.stderr}")


def derived(source: Path, out: Path, every: int, noise: float, seed: int = 0) -> Path:
    """``source`` with every ``every``-th pair (renumbered; odometry and truth follow)
    and Gaussian noise of ``noise`` x full scale on its LED frames."""
    (out / "frames").mkdir(parents=True)
    (out / "truth").mkdir()
    shutil.copy(source / "probe.toml", out)
    for f in (source / "truth").iterdir():
        if f.name != "poses.csv":
            shutil.copy(f, out / "truth")
    n = len(list((source / "frames").glob("laser_*.png")))
    kept = list(range(0, n, every))
    rng = np.random.default_rng(seed)
    for k, i in enumerate(kept):
        shutil.copy(source / "frames" / f"laser_{i:05d}.png", out / "frames" / f"laser_{k:05d}.png")
        led = cv2.imread(str(source / "frames" / f"led_{i:05d}.png"), cv2.IMREAD_UNCHANGED)
        if noise > 0:
            top = np.iinfo(led.dtype).max
            led = np.clip(led + rng.normal(0, noise * top, led.shape), 0, top).astype(led.dtype)
        cv2.imwrite(str(out / "frames" / f"led_{k:05d}.png"), led)
    for name in ("odometry.csv", "truth/poses.csv"):
        if (source / name).is_file():
            with (source / name).open(newline="") as fh:
                rows = {int(r["frame"]): r for r in csv.DictReader(fh)}
            with (out / name).open("w", newline="") as fh:
                writer = csv.DictWriter(fh, fieldnames=list(next(iter(rows.values()))))
                writer.writeheader()
                writer.writerows({**rows[i], "frame": k} for k, i in enumerate(kept))
    return out


def ratios(dataset: Path, poses_csv: Path) -> tuple[np.ndarray, np.ndarray]:
    """Per posed frame: the largest |error| / sigma of the four parameters, and alpha's
    sigma (deg)."""
    with (dataset / "truth" / "poses.csv").open(newline="") as fh:
        truth = {int(r["frame"]): r for r in csv.DictReader(fh)}
    worst, alpha_sigma = [], []
    with poses_csv.open(newline="") as fh:
        for row in csv.DictReader(fh):
            err = np.array([float(row[k]) - float(truth[int(row["frame"])][k]) for k in POSE])
            sigma = np.array([float(row[k]) for k in SIGMA])
            if np.all(np.isfinite(err)):
                worst.append(np.max(np.abs(err) / sigma))
                alpha_sigma.append(sigma[0])
    return np.array(worst), np.array(alpha_sigma)


def summary(values: np.ndarray, sigma: np.ndarray) -> str:
    if not len(values) or not np.all(np.isfinite(values)):
        return f"{'nan':>13} {'':>8}"
    return f"{np.median(values):5.2f} / {np.max(values):5.2f} {np.median(sigma):8.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one small run (smoke test)")
    parser.add_argument("--size", default="half", choices=("half", "full"))
    args = parser.parse_args()
    runs = QUICK if args.quick else RUNS
    print("|error| / sigma per frame (largest of alpha, beta, dx, dy): median / max over "
          "the run, and the median alpha sigma (deg)")
    print(f"{'run':<30} {'frames':>6}  {'pose (ring alone)':>22}  {'run (refined)':>22}")
    with tempfile.TemporaryDirectory() as tmp:
        made: dict[tuple[str, int], Path] = {}
        for name, scenario, pairs, every, noise in runs:
            key = (scenario, pairs)
            if key not in made:
                made[key] = Path(tmp) / f"{scenario}_{pairs}"
                pipestitch("simulate", "--scenario", scenario, "--pairs", str(pairs),
                           "--size", args.size, "--out", str(made[key]))
            dataset = made[key]
            if every > 1 or noise > 0:
                dataset = derived(made[key], Path(tmp) / f"{scenario}_{every}_{noise}", every,
                                  noise)
            out = Path(tmp) / f"out_{len(list(Path(tmp).iterdir()))}"
            pipestitch("pose", str(dataset), "--out", str(out / "pose"))
            pipestitch("run", str(dataset), "--out", str(out / "run"))
            ring = ratios(dataset, out / "pose" / "poses.csv")
            refined = ratios(dataset, out / "run" / "poses.csv")
            print(f"{name:<30} {len(refined[0]):>6}  {summary(*ring):>22}  "
                  f"{summary(*refined):>22}", flush=True)


if __name__ == "__main__":
    main()
