"""Medians of large arrays: numpy's values, from a radix selection.

``numpy.median`` sorts no more than it must: it partitions the values about their
middle rank(s) with introselect. Where numpy's partition is not vectorised (numpy 2.4
on the AMD machine of docs/benchmarks.md) that still costs 0.5-0.8 ms for 92,640
float32 values (the sample a laser frame's ridge noise is measured on: one frame's
ring takes two such medians), and partitioning about two ranks (an even count) takes
longer still. No library selects faster, so a float32 array's middle values are found
here by a radix selection (:func:`_middle_ranks`): each value's bits, mapped to an
unsigned key that sorts as the floats do, are counted by their top 11 bits, the values
in the bin that holds the middle rank are gathered, counted by their next 11 bits, and
so on to the whole key: three counting passes, two of them over a few per cent of the
values (~0.2 ms for those 92,640). The result is the values at the two middle ranks
themselves, averaged as numpy averages them (in the array's float type): the same
median to the bit. Where the middle is a zero, whose sign numpy's partition leaves to
the order of the values, and for other dtypes, numpy's partition is used (about the
upper middle rank only, the lower middle value being the largest below it).
"""

from __future__ import annotations

import numba
import numpy as np

from pipestitch._runtime import kernel_cache  # noqa: F401  (before the first kernel)

__all__ = ["mad_sigma", "median", "nanmedian"]

MAD_TO_SIGMA = 1.4826   # a normal distribution's sigma per median absolute deviation

# The radix selection's passes over a float32 key: (shift, mask) of each pass' digit.
_DIGITS = ((21, 0x7FF), (10, 0x7FF), (0, 0x3FF))


def median(values: np.ndarray) -> np.floating:
    """``numpy.median(values)`` of a float array (any shape), the same value.

    Other dtypes, empty arrays and arrays holding NaN (whose median is NaN) are left to
    ``numpy.median`` itself.

    Parameters
    ----------
    values : numpy.ndarray
        The values (the whole array).

    Returns
    -------
    numpy.floating
        The median, of the array's float type.
    """
    flat = np.ravel(values)
    if flat.dtype == np.float32 and flat.size:
        middle, count = _middle_ranks(flat, False)
        if count == flat.size and middle[0] != 0 and middle[1] != 0:
            return _average(middle, count)
    if flat.dtype.kind != "f" or flat.size == 0 or np.isnan(flat).any():
        return np.median(flat)
    upper = flat.size // 2
    part = np.partition(flat, upper)
    if flat.size % 2:
        return part[upper]
    return (part[:upper].max() + part[upper]) / 2


def nanmedian(values: np.ndarray) -> np.floating:
    """``numpy.nanmedian(values)`` of a float array: the median of its values that are not
    NaN (NaN when there are none, without numpy's warning)."""
    flat = np.ravel(values)
    if flat.dtype == np.float32 and flat.size:
        middle, count = _middle_ranks(flat, True)
        if count == 0:
            return flat.dtype.type(np.nan)
        if middle[0] != 0 and middle[1] != 0:
            return _average(middle, count)
    kept = flat[~np.isnan(flat)]
    return median(kept) if kept.size else flat.dtype.type(np.nan)


def mad_sigma(values: np.ndarray) -> float:
    """The robust sigma of ``values``: 1.4826 times their median absolute deviation from
    their median (NaN for an empty array)."""
    flat = np.ravel(values)
    if flat.size == 0:
        return float("nan")
    return MAD_TO_SIGMA * float(median(np.abs(flat - median(flat))))


def _average(middle: np.ndarray, count: int) -> np.floating:
    """The median from the values of the two middle ranks (:func:`_middle_ranks`), as
    numpy forms it: the upper one of an odd count, else their mean in their float type."""
    if count % 2:
        return middle[1]
    return (middle[0] + middle[1]) / 2


@numba.njit(cache=True, nogil=True, inline="always")
def _key(bits: np.uint32) -> int:
    """An unsigned key of a float32's bits that sorts as the floats do (NaN aside):
    negative values' bits inverted, positive values' with the sign bit set."""
    b = np.int64(bits)
    return 0xFFFFFFFF - b if b >= 0x80000000 else b + 0x80000000


@numba.njit(cache=True, nogil=True)
def _middle_ranks(values: np.ndarray, skip_nan: bool) -> tuple[np.ndarray, int]:
    """The values at ranks k - 1 and k of the sorted non-NaN ``values``, k = count // 2.

    Parameters
    ----------
    values : numpy.ndarray
        float32, 1-D, C order.
    skip_nan : bool
        Leave NaN out (True) or stop at the first one (False: count -1).

    Returns
    -------
    middle : numpy.ndarray
        float32 (2,): the values of ranks k - 1 (meaningless when k is 0) and k.
    count : int
        The non-NaN values counted (0: none, ``middle`` meaningless; -1: a NaN, with
        ``skip_nan`` False).
    """
    middle = np.zeros(2, np.float32)
    candidates = values
    count, rank = 0, 0
    below_key, below = -1, np.float32(0)   # the largest value left below the candidates
    for level in range(len(_DIGITS)):
        shift, mask = _DIGITS[level]
        bits = candidates.view(np.uint32)
        counts = np.zeros(mask + 1, np.int64)
        for i in range(candidates.size):
            if candidates[i] != candidates[i]:
                if not skip_nan:
                    return middle, -1
                continue
            counts[(_key(bits[i]) >> shift) & mask] += 1
        if level == 0:
            count = int(counts.sum())
            if count == 0:
                return middle, 0
            rank = count // 2
        digit, before = 0, 0
        while before + counts[digit] <= rank:
            before += counts[digit]
            digit += 1
        kept = np.empty(counts[digit], np.float32)
        n_kept = 0
        for i in range(candidates.size):
            x = candidates[i]
            if x != x:
                continue
            key = _key(bits[i])
            d = (key >> shift) & mask
            if d == digit:
                kept[n_kept] = x
                n_kept += 1
            elif d < digit and key > below_key:
                below_key, below = key, x
        rank -= before
        candidates = kept
    # every candidate left has the one key of rank k: the same float
    middle[1] = candidates[0]
    middle[0] = candidates[0] if rank >= 1 else below
    return middle, count
