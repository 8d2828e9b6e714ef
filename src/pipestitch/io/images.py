"""Reading and writing frames: 8- or 16-bit, grey or colour, with clear errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io.atomic import atomic_write_bytes

__all__ = ["read_image", "write_image"]


def read_image(path: str | Path) -> np.ndarray:
    """Read an image unchanged (dtype and channels as stored; colour as BGR).

    Raises
    ------
    DatasetError
        If the file is missing, empty or cannot be decoded.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(path, "file not found")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise DatasetError(path, "file is empty")
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(path, "cannot decode image (corrupt or not an image)")
    if img.dtype not in (np.uint8, np.uint16):
        raise DatasetError(path, f"expected 8- or 16-bit pixels, got {img.dtype}")
    return img


def write_image(path: str | Path, img: np.ndarray) -> Path:
    """Write a PNG (or any format OpenCV knows by extension) atomically."""
    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", img)
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the image")
    return atomic_write_bytes(path, buf.tobytes())
