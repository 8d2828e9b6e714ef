"""Occluders of any brightness: the reference test piece seen past a black, a dark grey
and a lit (brighter than the far wall) laser-holder arm and mirror mount.

The same simulated run three times (seed, trajectory, wall and holes identical; only
the brightness of the arm and mount in the LED frames differs), each processed end to
end twice in one process: ours (occluders found as what stays fixed in the image,
whatever its brightness, plus what is dark) and the baseline (only what is dark, as
before). Reported per run: holes found (recall), false detections (anything the truth
does not list: on an occluder it is a stripe taken for a defect), the roll reference
the run chose (a bright stripe taken for a water line makes it "invert-detected"), the
mosaic's SSIM against the true wall, and, for the grey and lit arms, the SSIM
difference to the black-arm run. Targets: no false detection with any arm; SSIM of
the lit-arm run within 0.02 of the black-arm run.

Run: python bench/occluders.py [--quick] [--size half|full] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from holes import evaluate
from mosaic import score, true_wall

import pipestitch.mosaic.occluders as occluders
from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.simulating import simulate_dataset
from pipestitch.simulate.scenarios import SCENARIOS

ARMS = (("black", "test_piece"), ("grey", "grey_arm"), ("lit", "lit_arm"))


def _reference(out: Path) -> str:
    """The roll reference the run chose (standards.json)."""
    try:
        state = json.loads((out / "standards.json").read_text())
    except (OSError, ValueError):
        return "?"
    ref = state.get("reference", {})
    return str(ref.get("source", "?")) if isinstance(ref, dict) else str(ref)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke run (CI): 10 pairs")
    parser.add_argument("--size", default="half", choices=("half", "full"))
    parser.add_argument("--keep", type=Path, help="keep datasets and outputs in this folder")
    args = parser.parse_args()
    static_frames = occluders.MIN_STATIC_FRAMES
    with tempfile.TemporaryDirectory(prefix="pipestitch-occluders-") as tmp:
        root = args.keep or Path(tmp)
        radius = SCENARIOS["test_piece"].pipe_diameter_mm / 2
        print(f"Occluders: the test piece past three arms ({args.size} size)")
        print(f"{'arm':>5} {'method':>8} | {'recall':>6} | {'false':>5} | {'reference':>16} | "
              f"{'SSIM':>6} | {'SSIM - black':>12}")
        black_ssim: dict[str, float] = {}
        for arm, name in ARMS:
            dataset = root / f"{name}_{args.size}"
            if not (dataset / "probe.toml").exists():
                simulate_dataset(SCENARIOS[name], dataset, seed=1, size=args.size,
                                 n_pairs=10 if args.quick else None, show_progress=False)
            for method, min_frames in (("ours", static_frames), ("dark", 10**9)):
                occluders.MIN_STATIC_FRAMES = min_frames   # the baseline: darkness alone
                try:
                    summary = run_dataset(dataset, root / f"out_{name}_{method}",
                                          show_progress=False)
                finally:
                    occluders.MIN_STATIC_FRAMES = static_frames
                holes = evaluate(dataset, summary, radius)
                ssim = score(dataset, summary, true_wall(dataset)).ssim
                black_ssim.setdefault(method, ssim) if arm == "black" else None
                diff = ssim - black_ssim[method]
                print(f"{arm:>5} {method:>8} | {100 * holes['recall']:5.0f}% | "
                      f"{holes['false']:5d} | {_reference(summary.out):>16} | {ssim:6.3f} | "
                      f"{diff:+12.3f}", flush=True)


if __name__ == "__main__":
    main()
