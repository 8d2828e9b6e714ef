"""The probe moving between the two frames of a pair: ``pipestitch pose`` and ``run``
against the simulator's truth, as the command runs now and unaware of the motion.

SPEC: "The probe moves a little between the two frames". Each dataset is a simulated run
whose LED frames are taken a share of the way to the next pair (``pipestitch simulate
--led-share``: the probe moves on along its smooth track, turning and moving sideways as
it goes), the laser frames where the truth puts them (truth/poses.csv: the laser frames'
poses); share 0 is the simulator's default, both frames taken together. For each: the
tilt error (the hypothesis nearer the truth, deg) of ``pose`` and of ``run``, median /
max over the frames, the spread of ``run``'s z errors about their mean (mm), and the
share ``run`` measured (its message: "line" where the wall under the laser line told it,
"overlaps" where the LED frames' patch shifts against the rings' poses did); "ours" is
the command as it is, "unaware" the same command with the LED frames' shift and share
taken as 0 (the ring divided by the LED frame as it lies, the rings' prior on the laser
frames' poses, the LED frames' poses stated): what pipestitch did before.

Each command runs as a subprocess, as a user runs it (accuracy, not speed).

Run: python bench/pair_motion.py [--quick]
"""

from __future__ import annotations

import argparse
import csv
import re
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

# (scenario, seed, pairs, share of a step between the laser and the LED frame)
RUNS = [(scenario, seed, pairs, share)
        for scenario, seed, pairs in (("corrosion", 0, 30), ("corrosion", 3, 12), ("hard", 3, 12),
                                      ("chart83", 3, 12), ("aluminium", 3, 12),
                                      ("chart83", 0, 12), ("aluminium", 0, 12))
        for share in (0.0, 0.2, 0.5)]
QUICK = [("corrosion", 1, 6, 0.3)]
UNAWARE = """
import sys
import pipestitch.pipeline.run as run
import pipestitch.pipeline.stitching as stitching
import pipestitch.pose.ring as ring
ring._led_shift = lambda *args: None
stitching.led_share = lambda *args: 0.0
run.laser_instant = lambda values, share, **_: dict(values)
run.laser_instant_poses = lambda poses, sigmas, share, **_: (dict(poses), dict(sigmas))
from pipestitch.cli.app import app
app(sys.argv[1:])
"""


def simulate(out: Path, scenario: str, seed: int, pairs: int, share: float) -> None:
    """The scenario's run with each LED frame taken ``share`` of the way to the next
    pair, the probe moving on along its smooth track (``pipestitch simulate
    --led-share``)."""
    from pipestitch.pipeline.simulating import simulate_dataset
    from pipestitch.simulate.scenarios import SCENARIOS

    simulate_dataset(replace(SCENARIOS[scenario], defects="none", led_share=share), out,
                     seed=seed, size="half", n_pairs=pairs, show_progress=False, workers=2)


def command(kind: str, verb: str, data: Path, out: Path) -> None:
    head = ([sys.executable, "-m", "pipestitch.cli"] if kind == "ours"
            else [sys.executable, "-c", UNAWARE])
    done = subprocess.run([*head, verb, str(data), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{verb} {data} ({kind}) failed:\n{done.stdout}{done.stderr}")


def errors(data: Path, poses_csv: Path) -> dict[str, np.ndarray]:
    """Per frame, of the hypothesis nearer the truth in tilt: the tilt error (deg), the
    offset error (mm, the larger of dx and dy), the largest |error| / stated sigma of
    the four pose parameters (the sigma poses.csv states, the chosen hypothesis's); and
    the z error (mm; nan where the file has none)."""
    with (data / "truth" / "poses.csv").open(newline="") as fh:
        truth = {r["frame"]: r for r in csv.DictReader(fh)}
    found: dict[str, list[float]] = {"tilt": [], "offset": [], "sigmas": [], "z": []}
    with poses_csv.open(newline="") as fh:
        for row in csv.DictReader(fh):
            true = truth[row["frame"]]
            error = {p: {k: float(row[p + k]) - float(true[k]) for k in POSE} for p in ("", "alt_")}
            p = min(error, key=lambda q: max(abs(error[q][k]) for k in POSE[:2]))
            found["tilt"].append(max(abs(error[p][k]) for k in POSE[:2]))
            found["offset"].append(max(abs(error[p][k]) for k in POSE[2:]))
            found["sigmas"].append(max(abs(error[p][k]) / float(row[s])
                                       for k, s in zip(POSE, SIGMA, strict=True)))
            found["z"].append(float(row["z_mm"]) - float(true["z_mm"]))
    return {k: np.array(v) for k, v in found.items()}


POSE = ("alpha_deg", "beta_deg", "dx_mm", "dy_mm")
SIGMA = ("alpha_std_deg", "beta_std_deg", "dx_std_mm", "dy_std_mm")


def cell(values: np.ndarray) -> str:
    return f"{np.nanmedian(values):.3f} / {np.nanmax(values):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one small run (smoke test)")
    args = parser.parse_args()
    print("tilt error (deg, the hypothesis nearer the truth): median / max over the frames; "
          "run's offset error (mm, the larger of dx and dy), median; run's largest "
          "|error| / stated sigma of a frame's four pose parameters, median; run's z "
          "errors' spread about their mean (mm); the share run measured and what told it")
    print(f"{'run':<22} {'share':>5}  {'pose ours':>15} {'pose unaware':>15}  "
          f"{'run ours':>15} {'run unaware':>15}  {'off ours':>8} {'unaw.':>6}  "
          f"{'e/s ours':>8} {'unaw.':>6}  {'z ours':>7} {'z unaw.':>7}  measured")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (scenario, seed, pairs, share) in enumerate(QUICK if args.quick else RUNS):
            data = Path(tmp) / f"data{k}"
            simulate(data, scenario, seed, pairs, share)
            found = {}
            for kind in ("ours", "unaware"):
                for verb in ("pose", "run"):
                    out = Path(tmp) / f"{verb}_{kind}_{k}"
                    command(kind, verb, data, out)
                    found[(kind, verb)] = errors(data, out / "poses.csv")
            said = (Path(tmp) / f"run_ours_{k}" / "problems.csv").read_text()
            measured = re.search(r"taken ([\d.]+) of a step \(([\d.]+) mm\) (\w+)", said)
            told = "overlaps" if "LED frames' overlaps" in said else "line"
            ours, unaware = found[("ours", "run")], found[("unaware", "run")]
            print(f"{f'{scenario} (seed {seed})':<22} {share:>5.1f}  "
                  f"{cell(found[('ours', 'pose')]['tilt']):>15} "
                  f"{cell(found[('unaware', 'pose')]['tilt']):>15}  "
                  f"{cell(ours['tilt']):>15} {cell(unaware['tilt']):>15}  "
                  f"{np.median(ours['offset']):8.3f} {np.median(unaware['offset']):6.3f}  "
                  f"{np.median(ours['sigmas']):8.2f} {np.median(unaware['sigmas']):6.2f}  "
                  f"{np.std(ours['z']):7.3f} {np.std(unaware['z']):7.3f}  "
                  + (" ".join([*measured.groups(), told]) if measured else "-"), flush=True)


if __name__ == "__main__":
    main()
