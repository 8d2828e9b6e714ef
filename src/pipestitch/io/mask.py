"""The occluder mask file (SPEC: probe.toml ``[probe] mask``): a camera-sized grey PNG
in the dataset, 0 where the camera never sees the wall, non-zero where it can.

:func:`read_mask` returns the mask as booleans, True where occluded (what the mosaic
stage takes); :func:`write_mask` writes such a mask in the file's convention (0 and
255), for ``pipestitch mask`` and for users to edit and reuse; :func:`mask_notes` says
when a mask hides most of where the ring must be (drawn the other way round?).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipestitch.config import ProbeConfig
from pipestitch.errors import DatasetError
from pipestitch.geometry import PipeSection, Pose, laser_ring
from pipestitch.io.images import read_image, write_image

__all__ = ["mask_notes", "mask_path", "read_mask", "write_mask"]


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


# A mask that hides more of a centred probe's ring than this is taken for one drawn the
# other way round: an arm hides a few per cent of the ring, and a ring mostly hidden
# leaves the ring search little to find whatever the reason.
MOSTLY_HIDDEN = 0.5


def mask_notes(occluded: np.ndarray | None, config: ProbeConfig) -> list[str]:
    """One warning when ``occluded`` (:func:`read_mask`; None: no mask) hides most of
    where the laser ring of a probe centred in the nominal pipe lies in the image, else
    none.

    The ring search takes no candidate where the mask says the camera never sees the
    wall, so a mask with 0 where the wall is seen leaves a run no ring.
    """
    if occluded is None:
        return []
    camera = config.camera_model()
    ring = laser_ring(Pose(), PipeSection.circle(config.pipe.inner_diameter_mm),
                      config.laser.plane_distance_mm, n_points=720,
                      plane_normal=np.asarray(config.laser.plane_normal(), float))
    pixels = np.rint(camera.project(ring))
    height, width = occluded.shape
    seen = (np.isfinite(pixels).all(axis=1) & (pixels[:, 0] >= 0) & (pixels[:, 0] < width)
            & (pixels[:, 1] >= 0) & (pixels[:, 1] < height))
    if not seen.any():
        return []
    cols, rows = pixels[seen].astype(np.int64).T
    hidden = float(np.mean(occluded[rows, cols]))
    if hidden <= MOSTLY_HIDDEN:
        return []
    return [f"the mask hides {hidden:.0%} of where the laser ring of a probe centred in the "
            f"nominal {config.pipe.inner_diameter_mm:g} mm pipe lies: is it inverted? (0 must "
            "mark where the camera never sees the wall; no ring is searched there)"]


def write_mask(path: str | Path, occluded: np.ndarray) -> Path:
    """Write a mask (True = occluded) as a grey PNG: 0 occluded, 255 wall; atomically."""
    occluded = np.asarray(occluded, bool)
    if occluded.ndim != 2:
        raise ValueError(f"write_mask: expected a 2-D mask, got shape {occluded.shape}")
    return write_image(path, np.where(occluded, 0, 255).astype(np.uint8))
