"""Writers of the run's outputs (SPEC "Outputs"), each atomic (temp file + rename).

* ``mosaic.png``: 8-bit grey, SPEC's wall-image convention (row i at theta =
  i·deg_per_px, column j at z0_mm + j·mm_per_px_axial); no-data pixels are 0 and data
  pixels are at least 1, so 0 always means "not seen".
* ``mosaic.ome.tif`` + ``tiles/``: the same as a pyramid (:mod:`pipestitch.io.tiles`).
* ``mosaic.json``: scale, origin and references of the mosaic.
* ``profile.csv``: per frame, the pipe's diameter from the laser ring.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io._image_kernels import scaled_uint8
from pipestitch.io.atomic import atomic_write_bytes, atomic_write_text
from pipestitch.io.images import read_image, write_image
from pipestitch.io.png import encode_png
from pipestitch.jsonsafe import json_safe

__all__ = ["DEFECT_COLUMNS", "PROFILE_COLUMNS", "intensity_scale", "mosaic_from_uint8",
           "mosaic_meta_problems", "mosaic_to_uint8",
           "read_mosaic", "write_csv", "write_json", "write_mosaic_png"]

PROFILE_COLUMNS = ("frame", "z_mm", "diameter_mm", "ovality", "min_radius_mm", "max_radius_mm",
                   "diameter_std_mm", "model", "within_tolerance", "ovality_std",
                   "major_axis_theta_deg", "departure_mm", "departure_theta_deg",
                   "departure_extent_deg")
DEFECT_COLUMNS = ("kind", "z_mm", "theta_deg", "clock", "diameter_mm", "area_mm2", "z_min_mm",
                  "z_max_mm", "theta_min_deg", "theta_max_deg", "contrast", "confidence",
                  "partial")


def intensity_scale(image: np.ndarray) -> float:
    """The value :func:`mosaic_to_uint8` maps to 250: the 99.5th percentile of the data
    (finite values), 1 without data."""
    finite = np.isfinite(image)
    scale = float(np.percentile(image[finite], 99.5)) if finite.any() else 1.0
    return scale if scale > 0 else 1.0


def mosaic_to_uint8(image: np.ndarray, scale: float | None = None) -> tuple[np.ndarray, float]:
    """Float mosaic (NaN = no data) -> uint8 with data in [1, 255] and no data 0.

    Returns the image and the value mapped to 250 (``scale``; by default
    :func:`intensity_scale`), which mosaic.json records as ``intensity_scale``. The
    arithmetic is float32's (the mosaic's own type; other images are converted).
    """
    image = np.asarray(image, np.float32)
    if image.ndim != 2:
        raise ValueError(f"mosaic_to_uint8: expected a 2-D mosaic, got shape {image.shape}")
    scale = intensity_scale(image) if scale is None else (scale if scale > 0 else 1.0)
    return scaled_uint8(image, scale), scale


def mosaic_from_uint8(image_u8: np.ndarray) -> np.ndarray:
    """The 8-bit mosaic back as float, NaN where there is no data (0)."""
    out = image_u8.astype(np.float32)
    out[image_u8 == 0] = np.nan
    return out


def write_mosaic_png(path: Path, image_u8: np.ndarray) -> Path:
    """Write the 8-bit mosaic atomically (a grey one by :func:`pipestitch.io.png.encode_png`,
    a colour one, BGR, by OpenCV)."""
    if image_u8.ndim == 2:
        return atomic_write_bytes(path, encode_png(image_u8))
    return write_image(path, image_u8)


def write_json(path: Path, data: Mapping[str, object]) -> Path:
    """Pretty JSON, atomically; non-finite floats become null."""
    return atomic_write_text(path, json.dumps(json_safe(data), indent=2) + "\n")


def write_csv(path: Path, header: Iterable[str], rows: Iterable[Iterable[object]]) -> Path:
    """CSV with floats to 6 decimals and nan for missing values, atomically."""
    def fmt(v: object) -> str:
        if isinstance(v, float | np.floating):
            return "nan" if not math.isfinite(v) else f"{v:.6f}"
        return str(v)

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(list(header))
    for row in rows:
        writer.writerow([fmt(v) for v in row])
    return atomic_write_text(path, buffer.getvalue())


def read_mosaic(out: Path, columns: Callable[[int], np.ndarray] | None = None,
                image: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """OUT/mosaic.png as float (NaN where no data) and OUT/mosaic.json.

    ``columns`` (the image width -> column indices) keeps only those columns, before the
    conversion to float (which takes four times the PNG's pixels in bytes); the image
    then no longer matches the metadata's column scale and origin, and is for per-column
    statistics only. Raises DatasetError naming the file when either is missing or
    unreadable, and naming the key when mosaic.json's scale or origin is impossible
    (:func:`mosaic_meta_problems`), before the image is read. ``image``: mosaic.png's
    pixels, when the caller holds them (the run that wrote it): not read again.
    """
    meta_path = Path(out) / "mosaic.json"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(meta_path, "missing (run `pipestitch run` first)") from None
    except (OSError, ValueError, RecursionError) as exc:
        raise DatasetError(meta_path, f"unreadable: {exc}") from None
    problems = mosaic_meta_problems(meta)
    if problems:
        raise DatasetError(meta_path, "; ".join(problems))
    if image is None:
        image = read_image(Path(out) / "mosaic.png")
    if image.ndim != 2:
        raise DatasetError(Path(out) / "mosaic.png", f"expected a grey image, got {image.shape}")
    return mosaic_from_uint8(image if columns is None else image[:, columns(image.shape[1])]), meta


# mosaic.json's grid keys: (key, lower bound, upper bound; None = any finite number).
_GRID_KEYS = (("mm_per_px_axial", 0.0, math.inf), ("deg_per_px", 0.0, 360.0),
              ("z0_mm", None, None))


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _number_problem(grid: Mapping[str, object], key: str, where: str, low: float | None,
                    high: float | None) -> str | None:
    value = grid.get(key)
    if key not in grid:
        return f"missing key {where}{key}"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{where}{key} = {_short(value)}: expected a number"
    try:
        finite = math.isfinite(value)
    except OverflowError:          # an integer beyond float range
        finite = False
    if not finite:
        return f"{where}{key} = {_short(value)}: expected a finite number"
    if low is not None and high is not None and not low < value <= high:
        return f"{where}{key} = {_short(value)}: expected > {low:g}" + (
            f" and <= {high:g}" if math.isfinite(high) else "")
    return None


def mosaic_meta_problems(meta: object) -> list[str]:
    """What is impossible in a mosaic.json document (empty when nothing): the scales
    ``mm_per_px_axial`` (> 0), ``deg_per_px`` (> 0, <= 360), the origin ``z0_mm``
    (finite) and ``radius_mm`` (> 0), the same of ``full_resolution`` when present
    (and its ``file``, a relative path inside the run folder), ``n_rows``/``n_cols``
    (whole numbers >= 0) and ``window_mm`` (two finite numbers) when present. Each
    names its key."""
    if not isinstance(meta, dict):
        return [f"expected a JSON object, got {type(meta).__name__}"]
    grids: list[tuple[Mapping[str, object], str]] = [(meta, "")]
    full = meta.get("full_resolution")
    problems: list[str | None] = []
    if "full_resolution" in meta:
        if isinstance(full, dict):
            grids.append((full, "full_resolution."))
            file = full.get("file")
            if (not isinstance(file, str) or not file or Path(file).is_absolute()
                    or ".." in Path(file).parts):
                problems.append(f"full_resolution.file = {_short(file)}: expected a file name "
                                "in the run folder")
        else:
            problems.append(f"full_resolution = {_short(full)}: expected an object")
    for grid, where in grids:
        for key, low, high in _GRID_KEYS:
            problems.append(_number_problem(grid, key, where, low, high))
        for key in ("n_rows", "n_cols"):
            value = grid.get(key)
            if key in grid and (isinstance(value, bool) or not isinstance(value, int)
                                or value < 0):
                problems.append(f"{where}{key} = {_short(value)}: expected a whole number >= 0")
    problems.append(_number_problem(meta, "radius_mm", "", 0.0, math.inf))
    window = meta.get("window_mm")
    if "window_mm" in meta and not (
            isinstance(window, list) and len(window) == 2
            and all(_number_problem({"v": v}, "v", "", None, None) is None for v in window)):
        problems.append(f"window_mm = {_short(window)}: expected two finite numbers")
    return [p for p in problems if p]
