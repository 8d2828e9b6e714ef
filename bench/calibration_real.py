"""Camera calibration on the real checkerboard images of ../shared/data vs the published one.

For each real data set: detect the boards, fit our model, and compare with the
calibration published with the images (OCamCalib's calib_results.txt, Urban's MATLAB
session, py-OCamCalib, the ROS fisheye K, D): reprojection RMS per image and overall,
and the mean |difference| of projected points over the image circle (incidence up
to 90°) and over the field the boards cover, raw and after the roll gauge (a
rotation about the optical axis that a calibration may put in its affine part or in
the views' extrinsics).

    python bench/calibration_real.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from pipestitch.calibrate import Board, calibrate_camera, compare_models, detect_board
from pipestitch.camera import OcamModel, fit_invpol
from pipestitch.io.images import read_image
from pipestitch.io.matlab import ocam_from_matlab
from pipestitch.io.ocamcalib import read_calib_results
from pipestitch.io.opencv_calib import read_opencv_fisheye

DATA = Path(os.environ.get("PIPESTITCH_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))


def _matlab_session(path: Path) -> OcamModel:
    m = json.loads(path.read_text())["ocam_model"]
    cam = OcamModel(pol=tuple(m["ss"]), invpol=(), center_row=m["xc"] - 1.0,
                    center_col=m["yc"] - 1.0, c=m["c"], d=m["d"], e=m["e"], width=m["width"],
                    height=m["height"])  # MATLAB session: 1-based row/column centre
    return OcamModel(pol=cam.pol, invpol=fit_invpol(cam), center_row=cam.center_row,
                     center_col=cam.center_col, c=cam.c, d=cam.d, e=cam.e, width=cam.width,
                     height=cam.height)


def _pyocamcalib(path: Path) -> OcamModel:
    c = json.loads(path.read_text())
    a = c["taylor_coefficient"]  # same form as MATLAB's, centre 0-based (x = column)
    return ocam_from_matlab({"MappingCoefficients": [a[0], a[2], a[3], a[4]],
                             "StretchMatrix": c["stretch_matrix"],
                             "DistortionCenter": [v + 1.0 for v in c["distortion_center"]],
                             "ImageSize": [778, 1032]}, path)


def _cases(quick: bool) -> list[tuple[str, str, Path, str, list[tuple[str, OcamModel]]]]:
    back = DATA / "ocam_urban_backcam_748x480"
    fish1 = DATA / "ocam_urban_fisheye1_1032x778"
    ros = DATA / "opencv_fisheye_ros_800x503"
    cases = [("backcam 748x480, imgBack (11 images)", "*.jpg", back / "images_imgBack", "ocam",
              [("OCamCalib calib_results.txt", read_calib_results(back / "calib_results.txt"))])]
    if quick:
        return cases
    cases += [
        ("backcam 748x480, Fisheye2 (5 images)", "*.jpg", back / "images_Fisheye2", "ocam",
         [("the MATLAB calibration by Urban of these images (16 images)",
           _matlab_session(back / "CalibData_ALL2_Fisheye2.json")),
          ("OCamCalib calib_results.txt (imgBack session)",
           read_calib_results(back / "calib_results.txt"))]),
        ("Fisheye1 1032x778 (10 images)", "*.jpg", fish1 / "images", "ocam",
         [("the MATLAB calibration by Urban (15 images)", _matlab_session(
             fish1 / "CalibData_ALL2_Fisheye1.json")),
          ("py-OCamCalib (12 images)", _pyocamcalib(
              fish1 / "pyocamcalib" / "calibration_fisheye_1_18052022_154907.json"))]),
        ("ROS 800x503 (9 images)", "*.png", ros / "images", "opencv_fisheye",
         [("ROS ost.yaml (24 images)", read_opencv_fisheye(ros / "ost.yaml"))]),
        ("ROS 800x503 (9 images)", "*.png", ros / "images", "ocam",
         [("ROS ost.yaml (24 images)", read_opencv_fisheye(ros / "ost.yaml"))]),
    ]
    return cases


def _covered_deg(cal, reference) -> float:
    """Largest incidence (reference model) of any corner used: the field the boards cover."""
    px = np.concatenate([v.pixels for v in cal.views])
    rays = reference.unproject(px)
    return float(np.rad2deg(np.nanmax(np.arccos(np.clip(rays[:, 2], -1, 1)))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one data set only")
    args = parser.parse_args()
    print("calibration vs published, real images (board 6x8 inner corners)")
    if not DATA.is_dir():
        print(f"no shared data at {DATA}: nothing to compare")
        return 0
    board = Board(6, 8, 32.5)  # the square size does not change the intrinsics
    for title, pattern, folder, model, references in _cases(args.quick):
        paths = sorted(folder.glob(pattern))
        start = time.perf_counter()
        views = [v for p in paths if (v := detect_board(read_image(p), board, name=p.name))]
        width, height = references[0][1].width, references[0][1].height
        cal = calibrate_camera(views, model=model, width=width, height=height)
        seconds = time.perf_counter() - start
        per_image = ", ".join(f"{v.name.split('.')[0]} {v.rms_px:.2f}" for v in cal.views)
        print(f"\n{title}: {model}, {len(cal.views)}/{len(paths)} views used, "
              f"{len(views)} boards found, {seconds:.1f} s")
        print(f"  reprojection RMS overall {cal.rms_px:.3f} px; per image: {per_image}")
        for name, reason in cal.rejected:
            print(f"  rejected {name}: {reason}")
        for ref_name, reference in references:
            covered = _covered_deg(cal, reference)
            full = compare_models(cal.camera, reference, max_incidence_deg=90.0)
            field = compare_models(cal.camera, reference, max_incidence_deg=covered)
            print(f"  vs {ref_name}: image circle <= 90°: mean |d| {full.mean_px:.2f} px "
                  f"(max {full.max_px:.2f}), roll-aligned {full.mean_aligned_px:.2f} px "
                  f"(max {full.max_aligned_px:.2f}, roll {full.roll_deg:+.2f}°); "
                  f"boards' field <= {covered:.0f}°: aligned {field.mean_aligned_px:.2f} px "
                  f"(max {field.max_aligned_px:.2f})")
        if len(references) > 1:
            (name_a, ref_a), (name_b, ref_b) = references[:2]
            between = compare_models(ref_b, ref_a, max_incidence_deg=90.0)
            print(f"  for scale, {name_b} vs {name_a}: roll-aligned "
                  f"{between.mean_aligned_px:.2f} px (max {between.max_aligned_px:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
