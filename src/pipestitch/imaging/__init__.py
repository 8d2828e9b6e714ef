"""Numerical helpers on images and large arrays, as OpenCV and numpy give them, faster.

* :mod:`~pipestitch.imaging.blur`: Gaussian blurs of float32 images through OpenCV's
  fastest route for their size;
* :mod:`~pipestitch.imaging.medians`: numpy's medians by a radix selection;
* :mod:`~pipestitch.imaging.scaling`: integer frames to float32, scaled, as numpy does it.

Imports OpenCV, numpy, numba and :mod:`pipestitch._runtime` only: any layer may import it.
"""

from pipestitch.imaging.blur import gaussian_blur, kernel_taps
from pipestitch.imaging.medians import MAD_TO_SIGMA, mad_sigma, median, nanmedian
from pipestitch.imaging.scaling import scaled_float32

__all__ = ["MAD_TO_SIGMA", "gaussian_blur", "kernel_taps", "mad_sigma", "median", "nanmedian",
           "scaled_float32"]
