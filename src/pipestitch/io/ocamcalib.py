"""OCamCalib ``calib_results.txt`` reader and writer.

The file holds five numeric lines (comments start with ``#``): the cam2world
polynomial (count first), the world2cam polynomial (count first), ``xc yc`` (row,
column, 0-based), ``c d e`` and ``height width``. See SPEC and shared/data/README.
"""

from __future__ import annotations

from pathlib import Path

from pipestitch.camera import OcamModel
from pipestitch.errors import ConfigError
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.text import read_config_text

__all__ = ["parse_calib_results", "read_calib_results", "write_calib_results"]


def _numeric_lines(text: str, path: Path) -> list[list[float]]:
    lines = []
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        try:
            lines.append([float(tok) for tok in line.split()])
        except ValueError as exc:
            raise ConfigError(path, f"non-numeric line in calib_results: {line[:60]!r}") from exc
    return lines


def _counted(line: list[float], what: str, path: Path) -> tuple[float, ...]:
    count = int(line[0])
    if count != len(line) - 1:
        raise ConfigError(path, f"{what}: header says {count} coefficients, found {len(line) - 1}")
    return tuple(line[1:])


def parse_calib_results(text: str, path: str | Path = "calib_results.txt") -> OcamModel:
    """Parse the text of a ``calib_results.txt`` into an :class:`OcamModel`."""
    path = Path(path)
    lines = _numeric_lines(text, path)
    if len(lines) < 5:
        raise ConfigError(path, f"expected 5 numeric lines (pol, invpol, centre, affine, size), "
                                f"found {len(lines)}")
    pol = _counted(lines[0], "pol (line 1)", path)
    invpol = _counted(lines[1], "invpol (line 2)", path)
    shapes = {"centre (line 3)": (lines[2], 2), "affine (line 4)": (lines[3], 3),
              "size (line 5)": (lines[4], 2)}
    for what, (line, n) in shapes.items():
        if len(line) != n:
            raise ConfigError(path, f"{what}: expected {n} numbers, found {len(line)}")
    (xc, yc), (c, d, e), (height, width) = lines[2], lines[3], lines[4]
    try:
        return OcamModel(pol=pol, invpol=invpol, center_row=xc, center_col=yc, c=c, d=d, e=e,
                         width=int(width), height=int(height))
    except ValueError as exc:
        raise ConfigError(path, str(exc)) from exc


def read_calib_results(path: str | Path) -> OcamModel:
    """Read an OCamCalib ``calib_results.txt``."""
    path = Path(path)
    text = read_config_text(path)
    return parse_calib_results(text, path)


def format_calib_results(cam: OcamModel) -> str:
    """The text of a ``calib_results.txt`` for ``cam`` (OCamCalib's layout)."""
    def counted(values: tuple[float, ...]) -> str:
        return f"{len(values)} " + " ".join(f"{v:.12e}" for v in values)

    return "\n".join([
        "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). "
        "These are used by cam2world", "", counted(cam.pol), "",
        "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). "
        "These are used by world2cam", "", counted(cam.invpol), "",
        '#center: "row" and "column", starting from 0 (C convention)', "",
        f"{cam.center_row:.9f} {cam.center_col:.9f}", "",
        '#affine parameters "c", "d", "e"', "", f"{cam.c:.9f} {cam.d:.9f} {cam.e:.9f}", "",
        '#image size: "height" and "width"', "", f"{cam.height} {cam.width}", "",
    ])


def write_calib_results(path: str | Path, cam: OcamModel) -> Path:
    """Write ``cam`` as an OCamCalib ``calib_results.txt`` (atomically)."""
    return atomic_write_text(path, format_calib_results(cam))
