"""``pipestitch mask``: the occluder mask found from a dataset's LED frames, as a file.

The mask the mosaic stage finds when probe.toml names none (:func:`find_occluders`),
written in SPEC's mask-file convention (grey PNG, 0 where the camera never sees the
wall), so that a user can look at it, edit it and name it in probe.toml
(``[probe] mask = "mask.png"``) for later runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io.dataset import open_dataset
from pipestitch.io.mask import mask_path, write_mask
from pipestitch.pipeline.progress import StageTimer
from pipestitch.pipeline.stitching import MosaicSettings, find_occluders, led_frames

__all__ = ["MaskSummary", "run_mask"]


@dataclass(frozen=True)
class MaskSummary:
    """What ``pipestitch mask`` reports."""

    path: Path
    occluded_fraction: float      # of the image's pixels
    n_frames: int                 # LED frames the mask was found from
    declared: Path | None         # the mask probe.toml names, if any


def run_mask(root: str | Path, out: str | Path, *, video: Path | None = None,
             frames: int = MosaicSettings.reference_frames, workers: int = 2) -> MaskSummary:
    """Find the occluders of a dataset from ``frames`` LED frames spread over the run and
    write the mask to ``out`` (a PNG path).

    Raises
    ------
    DatasetError
        When the dataset is invalid or has no LED frames.
    """
    dataset = open_dataset(root, video=video)
    if not dataset.has_led:
        raise DatasetError(Path(root) / "frames", "no LED frames: occluders are found from "
                                                  "the LED frames")
    if frames < 1:
        raise DatasetError(Path(root), f"--frames: expected at least 1, got {frames}")
    pairs = led_frames(dataset)
    try:
        occluded = find_occluders(dataset, pairs, min(frames, len(pairs)), StageTimer(),
                                  workers)
    finally:
        dataset.close()   # a video's decoder
    path = write_mask(out, occluded)
    return MaskSummary(path, float(np.mean(occluded)), min(frames, len(pairs)),
                       mask_path(root, dataset.config))
