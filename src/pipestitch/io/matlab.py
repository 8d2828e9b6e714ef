"""MATLAB ``fisheyeIntrinsics`` (Scaramuzza model) <-> :class:`OcamModel`.

MATLAB's Computer Vision Toolbox stores the same model as OCamCalib with other
conventions (the properties ``MappingCoefficients`` [a0 a2 a3 a4],
``StretchMatrix`` [c d; e 1], ``DistortionCenter`` [cx cy], ``ImageSize``
[rows cols]):

* frame x = column, y = row, z forward, so a0 > 0 (OCamCalib: x = row, a0 < 0);
* the stretch acts on (column, row) offsets: ``[u - cx; v - cy] = S·[x'; y']``;
* ``DistortionCenter`` is (x = column, y = row) and **1-based** (pixel centres at
  1, 1); OCamCalib's ``center`` is (row, column) 0-based;
* a1 = 0 and the polynomial has degree 4.

The conversion is exact: swapping rows and columns turns OCamCalib's
``[[c, d], [e, 1]]`` into ``[[1, e], [d, c]] = c·[[1/c, e/c], [d/c, 1]]``; the
factor c rescales ρ, hence ``g_i = −a_i·c^(1−i)`` (and the same the other way).

Files: JSON as MATLAB's ``jsonencode(intrinsics)`` writes it, or a ``.mat`` file
(``scipy.io``) holding those four variables, or a struct with them.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import scipy.io

from pipestitch.camera import OcamModel, fit_invpol
from pipestitch.errors import ConfigError
from pipestitch.io.atomic import atomic_write_bytes, atomic_write_text
from pipestitch.io.text import parse_json_object, read_config_text

__all__ = ["matlab_fields", "ocam_from_matlab", "read_matlab_fisheye", "write_matlab_fisheye"]

_KEYS = ("MappingCoefficients", "StretchMatrix", "DistortionCenter", "ImageSize")


def matlab_fields(camera: OcamModel) -> dict[str, list]:
    """MATLAB ``fisheyeIntrinsics`` properties describing ``camera`` exactly.

    Raises
    ------
    ValueError
        If ``camera.pol`` is not of MATLAB's form (a1 = 0, degree <= 4).
    """
    pol = np.zeros(5)
    if len(camera.pol) > 5 or (len(camera.pol) > 1 and abs(camera.pol[1]) > 1e-12):
        raise ValueError(f"MATLAB's fisheye model needs a1 = 0 and degree <= 4, got pol "
                         f"{camera.pol}")
    pol[:len(camera.pol)] = camera.pol
    c = camera.c
    g = -pol * c ** (1 - np.arange(5))
    return {
        "MappingCoefficients": [g[0], g[2], g[3], g[4]],
        "StretchMatrix": [[1.0 / c, camera.e / c], [camera.d / c, 1.0]],
        "DistortionCenter": [camera.center_col + 1.0, camera.center_row + 1.0],
        "ImageSize": [camera.height, camera.width],
    }


def ocam_from_matlab(fields: dict, path: str | Path = "fisheyeIntrinsics") -> OcamModel:
    """Build the :class:`OcamModel` from MATLAB ``fisheyeIntrinsics`` properties."""
    path = Path(path)
    missing = [k for k in _KEYS if k not in fields]
    if missing:
        raise ConfigError(path, f"missing key(s): {', '.join(missing)}")
    try:
        g = np.asarray(fields["MappingCoefficients"], float).ravel()
        s = np.asarray(fields["StretchMatrix"], float).reshape(2, 2)
        centre = np.asarray(fields["DistortionCenter"], float).ravel()
        size = np.asarray(fields["ImageSize"], float).ravel()
    except (TypeError, ValueError) as exc:
        raise ConfigError(path, f"MATLAB fisheye fields must be numeric arrays: {exc}") from exc
    shapes = {"MappingCoefficients": (g.size, 4), "DistortionCenter": (centre.size, 2),
              "ImageSize": (size.size, 2)}
    for key, (got, want) in shapes.items():
        if got != want:
            raise ConfigError(path, f"{key}: expected {want} numbers, got {got}")
    if not np.all(np.isfinite(np.concatenate([g, s.ravel(), centre, size]))):
        raise ConfigError(path, "MATLAB fisheye fields must be finite")
    if abs(s[1, 1] - 1.0) > 1e-9:
        raise ConfigError(path, f"StretchMatrix: expected [c d; e 1], got {s.tolist()}")
    big_c = s[0, 0]
    gfull = np.array([g[0], 0.0, g[1], g[2], g[3]])
    pol = -gfull * big_c ** (1 - np.arange(5))
    try:
        cam = OcamModel(pol=tuple(pol), invpol=(), center_row=centre[1] - 1.0,
                        center_col=centre[0] - 1.0, c=1.0 / big_c, d=s[1, 0] / big_c,
                        e=s[0, 1] / big_c, width=int(size[1]), height=int(size[0]))
        return OcamModel(pol=cam.pol, invpol=fit_invpol(cam), center_row=cam.center_row,
                         center_col=cam.center_col, c=cam.c, d=cam.d, e=cam.e,
                         width=cam.width, height=cam.height)
    except ValueError as exc:
        raise ConfigError(path, str(exc)) from exc


def _fields_from_mat(path: Path) -> dict:
    try:
        data = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
    except (ValueError, OSError, NotImplementedError) as exc:
        raise ConfigError(path, f"cannot read as a MATLAB .mat file: {exc}") from exc
    if all(k in data for k in _KEYS):
        return {k: data[k] for k in _KEYS}
    for value in data.values():  # a struct variable holding the four fields
        if all(hasattr(value, k) for k in _KEYS):
            return {k: getattr(value, k) for k in _KEYS}
    raise ConfigError(path, f"no variables or struct with {', '.join(_KEYS)}")


def read_matlab_fisheye(path: str | Path) -> OcamModel:
    """Read MATLAB fisheye intrinsics from ``.json`` (jsonencode) or ``.mat``."""
    path = Path(path)
    if path.suffix.lower() == ".mat":
        if not path.is_file():
            raise ConfigError(path, "file not found")
        return ocam_from_matlab(_fields_from_mat(path), path)
    data = parse_json_object(read_config_text(path), path, "MATLAB jsonencode(intrinsics)")
    return ocam_from_matlab(data, path)


def write_matlab_fisheye(path: str | Path, camera: OcamModel) -> Path:
    """Write ``camera`` as MATLAB fisheye intrinsics (``.json`` or ``.mat``), atomically."""
    path = Path(path)
    try:
        fields = matlab_fields(camera)
    except ValueError as exc:
        raise ConfigError(path, str(exc)) from exc
    if path.suffix.lower() == ".mat":
        buf = io.BytesIO()
        scipy.io.savemat(buf, {k: np.asarray(v, float) for k, v in fields.items()})
        return atomic_write_bytes(path, buf.getvalue())
    return atomic_write_text(path, json.dumps(fields, indent=2) + "\n")
