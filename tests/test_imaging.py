"""pipestitch.imaging: the Gaussian blur through filter2D is OpenCV's GaussianBlur."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.imaging import blur, gaussian_blur, kernel_taps

BORDERS = [cv2.BORDER_REFLECT_101, cv2.BORDER_REFLECT, cv2.BORDER_REPLICATE]


@pytest.mark.parametrize("shape", [(64, 48), (7, 300), (300, 7), (1, 1)])
@pytest.mark.parametrize("sigma", [0.5, 2.0, 6.0, 8.0, 20.0])
@pytest.mark.parametrize("border", BORDERS)
def test_blur_is_opencvs_gaussian_blur(shape: tuple[int, int], sigma: float,
                                       border: int) -> None:
    """Both routes, whole image and along rows, any border and images smaller than
    the kernel: GaussianBlur's result to float32 rounding (values in [0, 1])."""
    img = np.random.default_rng(0).random(shape).astype(np.float32)
    want = cv2.GaussianBlur(img, (0, 0), sigma, borderType=border)
    got = gaussian_blur(img, sigma, border=border)
    assert got.dtype == np.float32 and got.shape == img.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    taps = 2 * int(np.ceil(4 * sigma)) + 1
    want_rows = cv2.GaussianBlur(img, (taps, 1), sigmaX=sigma, sigmaY=0, borderType=border)
    got_rows = gaussian_blur(img, sigma, along_rows=True, taps=taps, border=border)
    np.testing.assert_allclose(got_rows, want_rows, rtol=0, atol=1e-6)


@pytest.mark.parametrize("sigma", [0.5, 6.0, 20.0])   # GaussianBlur, filter2D, GaussianBlur
@pytest.mark.parametrize("along_rows", [False, True])
def test_a_blur_written_into_a_given_array_is_the_same_blur(sigma: float,
                                                            along_rows: bool) -> None:
    """``out``: the blur is written into it and it is returned, on every route; its
    values are those of a blur into a new array, to the bit."""
    img = np.random.default_rng(2).random((30, 70)).astype(np.float32)
    taps = 2 * int(np.ceil(4 * sigma)) + 1 if along_rows else None
    want = gaussian_blur(img, sigma, along_rows=along_rows, taps=taps)
    out = np.full(img.shape, np.nan, np.float32)
    got = gaussian_blur(img, sigma, along_rows=along_rows, taps=taps, out=out)
    assert got is out
    np.testing.assert_array_equal(out, want)


def test_long_float32_kernels_take_filter2d_and_others_gaussian_blur(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The route: filter2D for float32 kernels of 11 to 129 taps, GaussianBlur for the
    rest and for other types (whose result is then GaussianBlur's exactly)."""
    calls = []
    real = cv2.filter2D
    monkeypatch.setattr(blur.cv2, "filter2D", lambda *a, **k: calls.append(1) or real(*a, **k))
    img = np.random.default_rng(1).random((40, 50)).astype(np.float32)
    gaussian_blur(img, 6.0)
    assert kernel_taps(6.0) == 49 and len(calls) == 2
    calls.clear()
    gaussian_blur(img, 0.5)      # 5 taps
    gaussian_blur(img, 17.0)     # 137 taps: filter2D would switch to a DFT
    assert calls == []
    grey = (img * 255).astype(np.uint8)
    np.testing.assert_array_equal(gaussian_blur(grey, 6.0), cv2.GaussianBlur(grey, (0, 0), 6.0))
    assert calls == []
