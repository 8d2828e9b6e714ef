"""The comparison strips' local contrast, compiled, against the numpy expressions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.imaging import gaussian_blur, nanmedian
from pipestitch.mosaic._photometric_kernels import ccs_modulus
from pipestitch.mosaic.photometric import _contrast, _peak_response, _spectrum, _z_window


def _numpy_contrast(strip: np.ndarray) -> np.ndarray:
    """The local contrast as numpy expressions (what the compiled passes replace)."""
    valid = np.isfinite(strip)
    filled = np.where(valid, strip, 0).astype(np.float32)
    weight = gaussian_blur(valid.astype(np.float32), 6.0)
    local = gaussian_blur(filled, 6.0) / np.maximum(weight, 1e-6)
    med = nanmedian(strip) if valid.any() else 0.0
    contrast = filled / np.maximum(local, 1e-6) - 1
    dark = ~valid | (filled < 0.3 * local) | (local < 0.25 * med)
    dark = cv2.dilate(dark.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return np.where(dark | (weight < 0.5), np.nan, contrast).astype(np.float32)


@pytest.mark.parametrize("case", ["textured", "holes and arm", "dim", "no data"])
def test_contrast_is_the_numpy_expressions_to_the_bit(case: str) -> None:
    rng = np.random.default_rng(3)
    strip = cv2.GaussianBlur(rng.random((96, 70)).astype(np.float32), (0, 0), 1.5) + 0.2
    if case == "holes and arm":
        strip[10:20, 5:15] = np.nan                 # unseen nodes
        strip[40:44, :] *= 0.05                     # a dark arm across the strip
        strip[60:63, 30:33] = 0.0                   # a hole
        strip[0, 0] = np.inf
    elif case == "dim":
        strip *= 1e-6                               # below the 1e-6 floors
    elif case == "no data":
        strip[:] = np.nan
    got = _contrast(strip)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, _numpy_contrast(strip))
    if case == "textured":
        assert np.isfinite(got).mean() > 0.5   # the comparison is not empty


def _numpy_modulus(spectrum: np.ndarray) -> np.ndarray:
    """OpenCV's ``magSpectrums`` of a packed (CCS) one-channel spectrum, as numpy
    expressions: each (re, im) pair's modulus in float64 rounded once at its real
    part, 0 at its imaginary part, |x| at the purely real entries."""
    rows, cols = spectrum.shape
    wide = spectrum.astype(np.float64)
    out = np.zeros_like(spectrum)
    last = cols - 1 if cols % 2 == 0 else cols
    out[:, 1:last:2] = np.sqrt(wide[:, 1:last:2] ** 2 + wide[:, 2:last + 1:2] ** 2)
    for c in {0, cols - 1} if cols % 2 == 0 else {0}:
        end = rows - 1 if rows % 2 == 0 else rows
        out[1:end:2, c] = np.sqrt(wide[1:end:2, c] ** 2 + wide[2:end + 1:2, c] ** 2)
        out[0, c] = abs(spectrum[0, c])
        if rows % 2 == 0:
            out[rows - 1, c] = abs(spectrum[rows - 1, c])
    return out


@pytest.mark.parametrize("shape", [(600, 120), (81, 45), (64, 33), (45, 64)])
def test_ccs_modulus_is_opencvs_magnitude_written_in_numpy(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    spectrum = cv2.dft(rng.standard_normal(shape).astype(np.float32), flags=cv2.DFT_REAL_OUTPUT)
    product = cv2.mulSpectrums(spectrum, spectrum[::-1].copy(), 0, conjB=True)
    got = ccs_modulus(product)
    np.testing.assert_array_equal(got, _numpy_modulus(product))
    # the quotient OpenCV's phase correlation forms: unit modulus wherever there is one
    unit = cv2.divSpectrums(product, got, 0, conjB=False)
    assert np.allclose(ccs_modulus(unit)[got > 1e-3], 1.0, atol=1e-5)


@pytest.mark.parametrize("shape", [(584, 112), (584, 100), (97, 61), (64, 40), (43, 25),
                                   (64, 45), (45, 64)])
def test_peak_response_is_phase_correlates_to_the_bit(shape: tuple[int, int]) -> None:
    # strips of texture, the second shifted and partly blank (as unseen wall is), and
    # sizes OpenCV pads to its DFT sizes in either direction or not at all (64 x 40), odd
    # ones (43 x 25 -> 45 x 25) and of mixed parity; the last trial shifts by about half
    # the strip, so the peak's 5 x 5 window is cut at the surface's edge
    rng = np.random.default_rng(shape[1])
    texture = cv2.GaussianBlur(rng.random((shape[0] + 20, shape[1] + 20)).astype(np.float32),
                               (0, 0), 1.2)
    a = np.ascontiguousarray(texture[:shape[0], :shape[1]])
    for trial in range(5):
        b = np.ascontiguousarray(texture[3 + trial:3 + trial + shape[0], 5:5 + shape[1]])
        if trial == 4:
            b = np.roll(a, (shape[0] // 2 - 1, shape[1] // 2 - 1), axis=(0, 1))
        b = b + np.float32(0.02) * rng.standard_normal(shape).astype(np.float32)
        b[:, :trial * 7] = 0.0
        window = _z_window(shape)
        # copies: phaseCorrelate may taper its inputs in place where it pads nothing
        _, expected = cv2.phaseCorrelate(b.copy(), a.copy(), window)
        assert _peak_response(_spectrum(b), _spectrum(a)) == expected
