"""probe.toml reader and writer (SPEC).

The reader reports every problem at once, naming the file, the section and the
key (unknown keys included); the writer produces a commented file that the reader
and OCamCalib users recognise.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ValidationError

from pipestitch.camera import CameraModel
from pipestitch.config import CameraConfig, ProbeConfig
from pipestitch.errors import ConfigError
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.text import read_config_text

M = TypeVar("M", bound=BaseModel)

__all__ = ["format_probe_toml", "parse_probe_toml", "probe_config_for", "read_probe_toml",
           "validated_toml",
           "write_probe_toml"]


def _describe(exc: ValidationError, *, sections: bool) -> str:
    """Every problem pydantic found, one phrase each: ``[section] key`` when the file's
    top level is sections (probe.toml), the dotted key otherwise (survey.toml)."""
    problems = []
    for err in exc.errors():
        loc = [str(p) for p in err["loc"]]
        if not loc:
            where = "(top level)"
        elif sections:
            where = f"[{loc[0]}] {'.'.join(loc[1:])}".strip()
        else:
            where = ".".join(loc)
        if err["type"] == "extra_forbidden":
            problems.append(f"unknown key {where}")
        elif err["type"] == "missing":
            problems.append(f"missing key {where}")
        elif not loc and err["type"] == "value_error":   # a check across sections
            problems.append(str(err["ctx"]["error"]))
        else:
            problems.append(f"{where}: {err['msg']}")
    return "; ".join(problems)


def validated_toml(text: str, path: Path, model: type[M], *, sections: bool) -> M:
    """``text`` parsed as TOML and validated as ``model``; ConfigError names ``path``
    and every problem (malformed TOML, unknown or missing keys, bad values).

    A leading UTF-8 byte-order mark (what Notepad and spreadsheets write) is dropped:
    TOML forbids it and tomllib would call the first line malformed.
    """
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, f"malformed TOML: {exc}") from None
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(path, _describe(exc, sections=sections)) from None


def parse_probe_toml(text: str, path: str | Path = "probe.toml") -> ProbeConfig:
    """Parse and validate probe.toml text; the camera model is built to check it."""
    path = Path(path)
    cfg = validated_toml(text, path, ProbeConfig, sections=True)
    try:
        cfg.camera_model()
    except ValueError as exc:
        raise ConfigError(path, f"[camera] {exc}") from exc
    return cfg


def read_probe_toml(path: str | Path) -> ProbeConfig:
    """Read and validate a probe.toml file."""
    path = Path(path)
    text = read_config_text(path)
    return parse_probe_toml(text, path)


def _value(v: object) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, float):
        return repr(v)
    return str(v)


_CAMERA_COMMENTS = {
    "pol": "cam2world F(rho), ascending powers, rho in px",
    "invpol": "world2cam rho(t), ascending, t = atan(z/sqrt(x²+y²))",
    "center": "xc yc = ROW, COLUMN of the centre, 0-based",
    "affine": "c d e",
    "K": "[[fx,0,cx],[0,fy,cy],[0,0,1]]",
    "D": "k1 k2 k3 k4",
}


_LASER_COMMENTS = {
    "normal": "pipestitch extension: calibrated unit normal of the plane n·p = d, probe frame",
}


def format_probe_toml(cfg: ProbeConfig) -> str:
    """probe.toml text for ``cfg`` (SPEC layout, with comments)."""
    out = ["# probe.toml written by pipestitch (see SPEC: frames, units, OCamCalib conventions)"]
    for section, model in (("camera", cfg.camera), ("laser", cfg.laser), ("probe", cfg.probe),
                           ("pipe", cfg.pipe)):
        values = model.model_dump(exclude_none=True)
        if not values:   # [probe] is optional: no body, no mask
            continue
        out.append(f"\n[{section}]")
        for key, v in values.items():
            comment = {"camera": _CAMERA_COMMENTS, "laser": _LASER_COMMENTS}.get(
                section, {}).get(key)
            out.append(f"{key} = {_value(v)}" + (f"  # {comment}" if comment else ""))
    return "\n".join(out) + "\n"


def write_probe_toml(path: str | Path, cfg: ProbeConfig) -> Path:
    """Write ``cfg`` to ``path`` atomically."""
    return atomic_write_text(path, format_probe_toml(cfg))


def probe_config_for(camera: CameraModel, *, plane_distance_mm: float, pipe_diameter_mm: float,
                     length_mm: float | None = None, diameter_mm: float | None = None,
                     plane_normal: list[float] | None = None) -> ProbeConfig:
    """Assemble a :class:`ProbeConfig` around a camera model (``plane_normal``: None = +z;
    no ``length_mm``/``diameter_mm``: no body constraint)."""
    laser: dict[str, object] = {"plane_distance_mm": plane_distance_mm}
    if plane_normal is not None:
        laser["normal"] = [float(v) for v in plane_normal]
    return ProbeConfig(camera=CameraConfig.from_model(camera), laser=laser,
                       probe={"length_mm": length_mm, "diameter_mm": diameter_mm},
                       pipe={"inner_diameter_mm": pipe_diameter_mm})
