"""Camera models: pure, vectorised maps between probe-frame rays and pixels; and the
camera's frames as grey values (:func:`to_grey`, in ``frames.py``).

Both models are valid over the whole field of view of a ~185° fisheye; see
``base.py`` for the shared conventions.

May import nothing else of pipestitch: it is the bottom layer with ``geometry``.
"""

from __future__ import annotations

from pipestitch.camera.base import CameraModel, pixel_grid
from pipestitch.camera.frames import blank_frame, mean_level, repair_pixels, to_grey
from pipestitch.camera.ocam import OcamModel, fit_invpol
from pipestitch.camera.opencv_fisheye import OpenCVFisheyeModel

__all__ = [
    "CameraModel",
    "OcamModel",
    "OpenCVFisheyeModel",
    "blank_frame",
    "default_camera",
    "fit_invpol",
    "mean_level",
    "pixel_grid",
    "repair_pixels",
    "to_grey",
]

# A 5 MP (2448 × 2048) ~185° fisheye like the reference design's: 90° at
# rho ≈ 965 px, 92.5° at rho ≈ 995 px, so the image circle just fits the sensor
# height. The centre is off the sensor centre and the affine part is not the
# identity, as in every real calibration, so code that assumes either is caught.
_DEFAULT_POL = (-620.0, 0.0, 6.2e-4, 1.0e-8, 4.0e-11)


def default_camera(size: str = "full") -> OcamModel:
    """The simulator's default camera.

    Parameters
    ----------
    size : {"full", "half"}
        ``"full"`` is 2448 × 2048, ``"half"`` the same lens at 1224 × 1024.
    """
    if size not in ("full", "half"):
        raise ValueError(f"size: expected 'full' or 'half', got {size!r}")
    base = OcamModel(pol=_DEFAULT_POL, invpol=(), center_row=1021.7, center_col=1226.4,
                     c=1.0002, d=0.0001, e=-0.0002, width=2448, height=2048)
    base = OcamModel(pol=base.pol, invpol=fit_invpol(base), center_row=base.center_row,
                     center_col=base.center_col, c=base.c, d=base.d, e=base.e,
                     width=base.width, height=base.height)
    return base if size == "full" else base.scaled(0.5)
