"""OpenCV fisheye calibrations (K, D = k1..k4) as YAML (cv2.FileStorage) or JSON.

YAML is read and written with ``cv2.FileStorage``. Reading accepts OpenCV's own
files (``!!opencv-matrix`` nodes) and ROS ``camera_info`` files (``rows/cols/data``
maps, no ``%YAML`` header), with the keys ``camera_matrix`` or ``K``,
``distortion_coefficients`` or ``D`` and ``image_width``/``image_height``. ROS's
fisheye calibrator labels its k1..k4 ``plumb_bob``; four coefficients are read as
fisheye k1..k4 whatever the label, anything else is rejected (a pinhole
``plumb_bob`` has five). JSON is ``{"model": "opencv_fisheye", "K": 3×3, "D": [4],
"width": W, "height": H}``. Pixels are OpenCV's: (column, row), 0-based.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from pipestitch.camera import OpenCVFisheyeModel
from pipestitch.errors import ConfigError
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.text import parse_json_object, read_config_text

__all__ = ["read_opencv_fisheye", "write_opencv_fisheye"]

_K_KEYS = ("camera_matrix", "K")
_D_KEYS = ("distortion_coefficients", "D")


def _model(k: np.ndarray, d: np.ndarray, width: int, height: int, path: Path
           ) -> OpenCVFisheyeModel:
    k = np.asarray(k, float)
    d = np.asarray(d, float).ravel()
    if k.shape != (3, 3):
        raise ConfigError(path, f"camera matrix K: expected 3 x 3, got shape {k.shape}")
    if d.size != 4:
        raise ConfigError(path, f"distortion D: expected the 4 fisheye coefficients k1..k4, "
                                f"got {d.size} (a 5-coefficient plumb_bob is a pinhole model)")
    if width <= 0 or height <= 0:
        raise ConfigError(path, f"image size: expected positive width and height, got "
                                f"{width} x {height}")
    try:
        return OpenCVFisheyeModel(fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]),
                                  cy=float(k[1, 2]), k=tuple(float(v) for v in d),
                                  width=int(width), height=int(height),
                                  skew=float(k[0, 1] / k[0, 0]) if k[0, 0] else 0.0)
    except ValueError as exc:
        raise ConfigError(path, str(exc)) from exc


def _node_matrix(node: cv2.FileNode) -> np.ndarray | None:
    """An ``!!opencv-matrix`` node or a ROS ``{rows, cols, data}`` map as an array."""
    if node.empty():
        return None
    if node.isMap() and not node.getNode("dt").empty():  # !!opencv-matrix
        return np.asarray(node.mat(), float)
    data = node.getNode("data") if node.isMap() else node
    if not data.isSeq():
        return None
    values = np.array([data.at(i).real() for i in range(data.size())])
    rows = int(node.getNode("rows").real()) if node.isMap() else 1
    return values.reshape(rows, -1)


def _first(fs: cv2.FileStorage, keys: tuple[str, ...]) -> np.ndarray | None:
    for key in keys:
        mat = _node_matrix(fs.getNode(key))
        if mat is not None:
            return mat
    return None


def _read_yaml(text: str, path: Path) -> OpenCVFisheyeModel:
    if not text.lstrip().startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text  # ROS camera_info files have no header
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:
        # OpenCV's parser raises cv2.error, or for some syntax errors (an unclosed "[")
        # a SystemError wrapping one
        cause = exc.__cause__ or exc.__context__ or exc
        lines = str(cause).strip().splitlines() or ["cannot parse"]
        raise ConfigError(path, f"malformed YAML: {lines[-1]}") from exc
    k, d = _first(fs, _K_KEYS), _first(fs, _D_KEYS)
    missing = [name for name, v in (("camera_matrix (K)", k), ("distortion_coefficients (D)", d))
               if v is None]
    width = int(fs.getNode("image_width").real() or fs.getNode("width").real())
    height = int(fs.getNode("image_height").real() or fs.getNode("height").real())
    if width <= 0 or height <= 0:
        missing.append("image_width/image_height")
    if missing:
        raise ConfigError(path, f"missing key(s): {', '.join(missing)}")
    return _model(k, d, width, height, path)


def _read_json(text: str, path: Path) -> OpenCVFisheyeModel:
    data = parse_json_object(text, path, "with K, D, width, height")
    missing = [key for key in ("K", "D", "width", "height") if key not in data]
    if missing:
        raise ConfigError(path, f"missing key(s): {', '.join(missing)}")
    if data.get("model", "opencv_fisheye") != "opencv_fisheye":
        raise ConfigError(path, f"model: expected 'opencv_fisheye', got {data['model']!r}")
    try:
        return _model(np.array(data["K"], float), np.array(data["D"], float),
                      int(data["width"]), int(data["height"]), path)
    except (TypeError, ValueError) as exc:
        raise ConfigError(path, f"K, D, width, height must be numbers: {exc}") from exc


def read_opencv_fisheye(path: str | Path) -> OpenCVFisheyeModel:
    """Read an OpenCV fisheye calibration (``.yaml``/``.yml`` or ``.json``)."""
    path = Path(path)
    text = read_config_text(path)
    if path.suffix.lower() == ".json":
        return _read_json(text, path)
    return _read_yaml(text, path)


def write_opencv_fisheye(path: str | Path, camera: OpenCVFisheyeModel) -> Path:
    """Write ``camera`` as YAML (cv2.FileStorage) or JSON, by the file's suffix, atomically."""
    path = Path(path)
    k, d = camera.camera_matrix, np.array(camera.k, float).reshape(1, 4)
    if path.suffix.lower() == ".json":
        data = {"model": "opencv_fisheye", "K": k.tolist(), "D": d.ravel().tolist(),
                "width": camera.width, "height": camera.height}
        return atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    fs = cv2.FileStorage(path.name, cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", camera.width)
    fs.write("image_height", camera.height)
    fs.write("distortion_model", "fisheye")
    fs.write("camera_matrix", k)
    fs.write("distortion_coefficients", d)
    return atomic_write_text(path, fs.releaseAndGetString())
