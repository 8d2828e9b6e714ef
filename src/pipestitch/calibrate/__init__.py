"""Calibration: camera intrinsics from checkerboard views and the laser plane from rings.

Pure algorithms on arrays (no file reading): :mod:`checkerboard` finds boards,
:mod:`ocam_fit` and :mod:`fisheye_fit` fit the two camera models,
:mod:`camera_fit` rejects bad views and reports residuals, :mod:`compare` measures
how far two models disagree, :mod:`laser_plane` fits the laser plane's normal and
distance. Files and the command line are in :mod:`pipestitch.pipeline.calibrating` and
:mod:`pipestitch.cli.calibrate_command`.

May import ``camera``, ``geometry``, ``errors``; must not import ``io``, ``pipeline``,
``cli``, ``simulate`` or ``report``.
"""

from __future__ import annotations

from pipestitch.calibrate.camera_fit import (
    CameraCalibration,
    ViewResidual,
    calibrate_camera,
    reprojection,
)
from pipestitch.calibrate.checkerboard import Board, BoardView, detect_board, parse_board
from pipestitch.calibrate.compare import ModelDifference, compare_models
from pipestitch.calibrate.fisheye_fit import fit_opencv_fisheye
from pipestitch.calibrate.laser_plane import (
    LaserPlaneFit,
    calibrate_laser_plane,
    normal_tilt_deg,
    plane_intersections,
)
from pipestitch.calibrate.ocam_fit import fit_ocam

__all__ = [
    "Board",
    "BoardView",
    "CameraCalibration",
    "LaserPlaneFit",
    "ModelDifference",
    "ViewResidual",
    "calibrate_camera",
    "calibrate_laser_plane",
    "compare_models",
    "detect_board",
    "fit_ocam",
    "fit_opencv_fisheye",
    "normal_tilt_deg",
    "parse_board",
    "plane_intersections",
    "reprojection",
]
