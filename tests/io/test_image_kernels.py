"""The compiled 8-bit mosaic conversion against the numpy expression it replaces, and
the PNG scanline filters against the PNG spec's definitions."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.io._image_kernels import png_paeth_filter, png_unfilter, scaled_uint8

RNG = np.random.default_rng(7)


def test_scaled_uint8_is_the_numpy_conversion() -> None:
    image = (3 * RNG.random((40, 50))).astype(np.float32)
    image[3, :9] = np.nan
    image[4, :3] = np.inf
    image[5, :4] = 0   # data, mapped to 1
    finite = np.isfinite(image)
    want = np.zeros(image.shape, np.uint8)
    want[finite] = np.clip(np.rint(image[finite] / 1.7 * 250), 1, 255).astype(np.uint8)
    np.testing.assert_array_equal(scaled_uint8(image, 1.7), want)


# --- PNG scanline filters: the compiled unfilter against the spec ---------------------

def _spec_paeth(left: np.ndarray, above: np.ndarray, corner: np.ndarray) -> np.ndarray:
    """The Paeth predictor as the PNG spec writes it (section 9.4)."""
    p = left + above - corner
    pa, pb, pc = np.abs(p - left), np.abs(p - above), np.abs(p - corner)
    return np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, above, corner))


def test_paeth_predictor_is_the_spec_s_on_every_byte_triple() -> None:
    """Every (left, above, upper-left) byte triple, through the compiled filter: a
    two-row image whose second pixel (65,536 bytes wide) has the triple's left byte
    in the first pixel of its row and its upper and upper-left bytes above them, and
    0 itself, so that the filtered byte is minus the predictor."""
    pair = np.arange(1 << 16)
    left, above = (pair >> 8).astype(np.uint8), (pair & 255).astype(np.uint8)
    for corner in range(256):
        image = np.zeros((2, 2 << 16), np.uint8)
        image[0, : 1 << 16], image[0, 1 << 16:] = corner, above
        image[1, : 1 << 16] = left
        image.flags.writeable = False   # as the encoder is called
        got = (-png_paeth_filter(image, 1 << 16)[1, 1 + (1 << 16):].astype(np.int32)) & 255
        want = _spec_paeth(left.astype(np.int32), above.astype(np.int32), corner)
        np.testing.assert_array_equal(got, want)


def _spec_filtered(image: np.ndarray, kinds: np.ndarray, step: int) -> np.ndarray:
    """``image`` (rows, row bytes) filtered row by row with the filter ``kinds[y]``, each
    byte from the unfiltered bytes as the PNG spec defines it; a filter byte first."""
    rows, n = image.shape
    img = np.pad(image.astype(np.int32), ((1, 0), (step, 0)))   # zeros outside the image
    out = np.empty((rows, n + 1), np.uint8)
    for y in range(rows):
        x, cur, up = img[y + 1, step:], img[y + 1, :-step], img[y, step:]
        corner = img[y, :-step]
        prediction = {0: 0, 1: cur, 2: up, 3: (cur + up) // 2,
                      4: _spec_paeth(cur, up, corner)}[int(kinds[y])]
        out[y, 0], out[y, 1:] = kinds[y], (x - prediction) & 255
    return out


@pytest.mark.parametrize("step", [1, 2, 3, 4, 6, 8])
@pytest.mark.parametrize("width", [1, 2, 3, 4, 5, 9, 37])
def test_unfilter_undoes_every_filter_in_any_order_of_rows(step: int, width: int) -> None:
    """Random bytes and a random filter for each row, with runs of Paeth rows of every
    length from 1 to 9 (which are unfiltered four at a time), the first row among them
    or not: the image itself, byte for byte."""
    rng = np.random.default_rng(step * 100 + width)
    for run in range(1, 10):
        kinds = rng.integers(0, 5, 20)
        start = int(rng.integers(0, 3))
        kinds[start:start + run] = 4
        image = rng.integers(0, 256, (20, width * step), dtype=np.uint8)
        raw = _spec_filtered(image, kinds, step).ravel()
        raw.flags.writeable = False
        out = np.full(image.size, 0xAB, np.uint8)   # nothing read before it is written
        assert png_unfilter(raw, image.shape[0], image.shape[1], step, out)
        np.testing.assert_array_equal(out.reshape(image.shape), image)


@pytest.mark.parametrize("bad_row", [0, 2, 5])
def test_unfilter_refuses_an_unknown_filter(bad_row: int) -> None:
    """A filter byte above 4 anywhere, also among Paeth rows unfiltered four at a time:
    False, the rows before it unfiltered."""
    image = np.random.default_rng(bad_row).integers(0, 256, (8, 6), dtype=np.uint8)
    raw = _spec_filtered(image, np.full(8, 4), 1)
    raw[bad_row, 0] = 5
    raw.flags.writeable = False
    out = np.zeros(image.size, np.uint8)
    assert not png_unfilter(raw.ravel(), 8, 6, 1, out)
    np.testing.assert_array_equal(out.reshape(image.shape)[:bad_row], image[:bad_row])
