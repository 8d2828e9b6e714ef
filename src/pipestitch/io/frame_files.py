"""The frame files of a dataset's frames/ folder, by their SPEC names.

A module of its own, importing nothing heavy, so that a command can find a run's frames
before it has loaded its stages (:mod:`pipestitch.pipeline.warm_start`).
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["IMAGE_EXTENSIONS", "frame_files", "frame_twins"]

IMAGE_EXTENSIONS = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp")
# SPEC's names: the pair's number zero-padded to five digits, so a run of 100,000 pairs
# or more goes on with six (laser_100000.png); a number padded further
# (laser_000001.png) is not a frame's name.
_FRAME_RE = re.compile(r"^(laser|led)_([0-9]{5}|[1-9][0-9]{5,})(\.[A-Za-z]+)$")


def frame_files(frames_dir: Path) -> tuple[dict[str, dict[int, Path]], list[Path]]:
    """The laser and LED frame files of a frames/ folder, and its other files.

    Parameters
    ----------
    frames_dir : pathlib.Path
        The folder (raises OSError when it cannot be listed).

    Returns
    -------
    tuple
        ({"laser": {index: path}, "led": {index: path}}, [other paths]). Of two files
        with one frame's name (``laser_00000.png`` and ``.tif``), the last in name order
        is the frame and the others are in the other paths (:func:`frame_twins`).
    """
    found: dict[str, dict[int, Path]] = {"laser": {}, "led": {}}
    other = []
    for path in sorted(frames_dir.iterdir()):
        m = _FRAME_RE.match(path.name)
        if m and m.group(3).lower() in IMAGE_EXTENSIONS:
            kind, index = m.group(1), int(m.group(2))
            if index in found[kind]:
                other.append(found[kind][index])
            found[kind][index] = path
        else:
            other.append(path)
    return found, other


def frame_twins(found: dict[str, dict[int, Path]], other: list[Path]) -> list[tuple[Path, Path]]:
    """(other file, the frame) for each other path that :func:`frame_files` set aside
    because a later file has its frame's name: which of the two is the frame is not
    said by the names (bad input)."""
    twins = []
    for path in other:
        m = _FRAME_RE.match(path.name)
        if m and m.group(3).lower() in IMAGE_EXTENSIONS:
            twins.append((path, found[m.group(1)][int(m.group(2))]))
    return twins
