"""Medians of large arrays: numpy's values, from one partition instead of two.

``numpy.median`` of an even number of values partitions about the two middle ranks at
once, and numpy (2.x) partitions about several ranks with its generic introselect, but
about a single rank with a vectorised one: 1.1 against 0.09 ms for 140,000 float32
values (the sample a laser frame's ridge noise is measured on). :func:`median`
partitions about the upper middle rank and takes the largest value below it, the
lower middle one: the same two values, averaged as numpy averages them (in the
array's float type), so the same median to the bit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["mad_sigma", "median", "nanmedian"]

MAD_TO_SIGMA = 1.4826   # a normal distribution's sigma per median absolute deviation


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
    kept = flat[~np.isnan(flat)]
    return median(kept) if kept.size else flat.dtype.type(np.nan)


def mad_sigma(values: np.ndarray) -> float:
    """The robust sigma of ``values``: 1.4826 times their median absolute deviation from
    their median (NaN for an empty array)."""
    flat = np.ravel(values)
    if flat.size == 0:
        return float("nan")
    return MAD_TO_SIGMA * float(median(np.abs(flat - median(flat))))
