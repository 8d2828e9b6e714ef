"""OpenCV fisheye (Kannala-Brandt, K and D = k1..k4) fitted with ``cv2.fisheye.calibrate``.

Field-of-view limit: OpenCV's fisheye functions normalise a point by its depth
(``x / z``) before taking ``theta = atan(r)``, so a board corner at or beyond 90°
from the optical axis (z <= 0) cannot be represented during the fit; such views
fail or bias the fit. Boards must therefore be seen within ~85° of the axis; the
fitted polynomial is then extrapolated by :class:`pipestitch.camera.OpenCVFisheyeModel`
(which evaluates it on the true incidence angle) out to the ~95° rim of a 185°
lens — check the rim with an ocam fit if the rim matters. Skew is held at zero
(``CALIB_FIX_SKEW``), as nearly every calibration tool does.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from pipestitch.calibrate.checkerboard import BoardView
from pipestitch.camera import OpenCVFisheyeModel

__all__ = ["fit_opencv_fisheye"]


def _flag(name: str) -> int:
    """A fisheye flag: ``cv2.fisheye.X`` up to OpenCV 4, the shared ``cv2.X`` from 5 on."""
    return int(getattr(cv2.fisheye, name, None) or getattr(cv2, name))


def fit_opencv_fisheye(views: Sequence[BoardView], width: int, height: int
                       ) -> tuple[OpenCVFisheyeModel, list[tuple[np.ndarray, np.ndarray]]]:
    """Fit OpenCV's fisheye model to checkerboard views.

    Parameters
    ----------
    views : sequence of BoardView
        At least 3 views.
    width, height : int
        Image size in pixels.

    Returns
    -------
    camera : OpenCVFisheyeModel
    poses : list of (rotation (3, 3), translation (3,))
        ``R_probe_board`` and ``t`` (mm) per view (OpenCV's camera frame is the
        SPEC probe frame).

    Raises
    ------
    ValueError
        When OpenCV cannot fit the views (its message is included).
    """
    if len(views) < 3:
        raise ValueError(f"opencv_fisheye fit: expected at least 3 views, got {len(views)}")
    # (1, N, 3) and (1, N, 2): the shape OpenCV 4 and 5 both accept.
    obj = [v.object_mm.reshape(1, -1, 3).astype(np.float64) for v in views]
    img = [v.pixels.reshape(1, -1, 2).astype(np.float64) for v in views]
    # OpenCV's documented start (centre of the image, f = max(w, h)/pi), passed
    # explicitly: OpenCV 5 without a guess fails to initialise boards that it fits
    # fine from this start (measured on the real 180° backcam views).
    f0 = max(width, height) / np.pi
    k0 = np.array([[f0, 0.0, (width - 1) / 2], [0.0, f0, (height - 1) / 2], [0.0, 0.0, 1.0]])
    flags = (_flag("CALIB_RECOMPUTE_EXTRINSIC") | _flag("CALIB_FIX_SKEW")
             | _flag("CALIB_USE_INTRINSIC_GUESS"))
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)
    try:
        _, k, d, rvecs, tvecs = cv2.fisheye.calibrate(obj, img, (width, height), k0, np.zeros(4),
                                                      flags=flags, criteria=criteria)
    except cv2.error as exc:
        raise ValueError(f"opencv_fisheye fit: cv2.fisheye.calibrate failed: "
                         f"{str(exc).strip().splitlines()[-1]}") from exc
    camera = OpenCVFisheyeModel(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]),
                                cy=float(k[1, 2]),
                                k=tuple(float(v) for v in np.ravel(d)[:4]), width=width,
                                height=height)
    poses = [(cv2.Rodrigues(np.asarray(r, float))[0], np.asarray(t, float).ravel())
             for r, t in zip(rvecs, tvecs, strict=True)]
    return camera, poses
