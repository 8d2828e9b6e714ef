"""Optional ``DATASET/imu.csv``: ``frame,roll_deg``, the probe's roll about the pipe axis
measured against gravity (an inclinometer/IMU on the probe).

``roll_deg`` is SPEC's gamma of that frame in a pipe frame whose +y points down (so the
crown is at theta = 270 deg): 0 when the image's up direction points at the crown;
image up then points at theta = 270 + roll_deg, so +90 puts it at 3 o'clock (see
docs/conventions.md, "Clock positions"). Extra columns are ignored.
"""

from __future__ import annotations

import math
from pathlib import Path

from pipestitch.errors import DatasetError
from pipestitch.io.dataset import check_frame_column, read_csv_lines

__all__ = ["IMU_FILE", "read_imu"]

IMU_FILE = "imu.csv"


def read_imu(dataset: str | Path) -> dict[int, float] | None:
    """Roll per frame from ``dataset/imu.csv``, or None when the file is absent.

    A frame whose roll_deg is ``nan`` or empty had no reading: it is left out, as a frame
    without a row is (the roll reference takes the frames that have one).

    Raises
    ------
    DatasetError
        Naming the file (and the line): missing columns, values that are neither
        numbers nor ``nan``/empty, frame numbers that are not whole numbers >= 0,
        repeated frames, no rows, no reading at all. A UTF-8 byte-order mark is accepted.
    """
    path = Path(dataset) / IMU_FILE
    if not path.is_file():
        return None
    cols, lines = read_csv_lines(path, ("frame", "roll_deg"), unread=("roll_deg",))
    frames = cols["frame"]
    if not len(frames):
        raise DatasetError(path, "no rows (expected frame,roll_deg per frame)")
    check_frame_column(path, frames, lines)
    roll = {int(f): float(r) for f, r in zip(frames, cols["roll_deg"], strict=True)
            if math.isfinite(r)}
    if not roll:
        raise DatasetError(path, "no reading: roll_deg is nan or empty on every row")
    return roll
