"""The occluder mask file (SPEC: probe.toml ``[probe] mask``): a camera-sized grey PNG
in the dataset, 0 where the camera never sees the wall, non-zero where it can.

:func:`read_mask` returns the mask as booleans, True where occluded (what the mosaic
stage takes); :func:`write_mask` writes such a mask in the file's convention (0 and
255), for ``pipestitch mask`` and for users to edit and reuse.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipestitch.config import ProbeConfig
from pipestitch.errors import DatasetError
from pipestitch.io.images import read_image, write_image

__all__ = ["mask_path", "read_mask", "write_mask"]


def mask_path(root: str | Path, config: ProbeConfig) -> Path | None:
    """The mask file probe.toml names, inside the dataset ``root`` (None: none named)."""
    if config.probe.mask is None:
        return None
    return Path(root) / config.probe.mask


def read_mask(root: str | Path, config: ProbeConfig) -> np.ndarray | None:
    """The dataset's occluder mask, True where the camera never sees the wall.

    Returns None when probe.toml names no mask.

    Raises
    ------
    DatasetError
        Naming the file: missing, unreadable, not grey, not the camera's size, or
        occluding every pixel.
    """
    path = mask_path(root, config)
    if path is None:
        return None
    if Path(config.probe.mask).is_absolute() or ".." in Path(config.probe.mask).parts:
        raise DatasetError(path, "mask: expected a file inside the dataset folder (SPEC)")
    image = read_image(path)
    if image.ndim != 2:
        raise DatasetError(path, f"mask: expected a grey image, got {image.shape[2]} channels")
    size = (config.camera.width, config.camera.height)
    if (image.shape[1], image.shape[0]) != size:
        raise DatasetError(path, f"mask is {image.shape[1]}x{image.shape[0]}, probe.toml says "
                                 f"{size[0]}x{size[1]}")
    occluded = image == 0
    if occluded.all():
        raise DatasetError(path, "mask is 0 everywhere: no pixel could see the wall")
    return occluded


def write_mask(path: str | Path, occluded: np.ndarray) -> Path:
    """Write a mask (True = occluded) as a grey PNG: 0 occluded, 255 wall; atomically."""
    occluded = np.asarray(occluded, bool)
    if occluded.ndim != 2:
        raise ValueError(f"write_mask: expected a 2-D mask, got shape {occluded.shape}")
    return write_image(path, np.where(occluded, 0, 255).astype(np.uint8))
