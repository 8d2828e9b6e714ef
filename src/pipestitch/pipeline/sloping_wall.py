"""``pipestitch pose``: frames whose ring lies where the pipe's radius changes along it.

The ring fit takes the wall at the ring for a cylinder. Where the pipe narrows or
widens (a reducer, a taper, a socket), a tilted ring spans a wall that is wider on one
side than on the other, and the fit's offset and tilt are off by up to
:func:`pipestitch.pose.section.sloping_wall_spread` (a reducer's frames: offsets
0.15-0.33 mm off with a stated sigma of 0.02-0.05 mm). ``pipestitch run`` measures
the wall along each strip and refines the poses from the LED frames; ``pose`` has
the rings and, where the dataset has an odometer, their z: the radius change between a
frame's neighbours per mm of z is the wall's slope there. Where it is significant the
chosen pose's stated sigmas are widened by that spread and the frame says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from pipestitch.pipeline.posing import FramePose
from pipestitch.pose.ambiguity import Choice
from pipestitch.pose.fit import PARAMS, Hypothesis
from pipestitch.pose.section import sloping_wall_spread

__all__ = ["SLOPE_SIGMAS", "SLOPING_WALL_WARNING", "on_sloping_wall"]

# A radius change between a frame's neighbours is the wall's when it is this many of
# its sigmas (both rings' radius sigmas combined): below, ring noise.
SLOPE_SIGMAS = 3.0
SLOPING_WALL_WARNING = ("the pipe's radius changes by {slope:.3f} mm per mm here (a reducer, a "
                        "taper?): the ring takes the wall as straight, so its offset may be off "
                        "by up to {bias:.2f} mm and its tilt by {tilt:.2f} deg (sigmas widened; "
                        "`pipestitch run` measures the wall)")


def on_sloping_wall(frames: Sequence[FramePose], choices: Sequence[Choice],
                    odometry_mm: Mapping[int, float] | None, plane_distance_mm: float
                    ) -> list[FramePose]:
    """``frames`` with the chosen pose's stated sigmas widened where the wall slopes.

    The slope at a frame is the change of the chosen rings' radius between the posed
    frames before and after it (the frame itself at either end of the run) over their
    odometer z; it counts where that change is over :data:`SLOPE_SIGMAS` of its sigma.
    The spread is at most that change (a ring cannot be misled by more than the radius
    change it straddles: this bounds it where the neighbours' z are close). Frames
    without an odometer reading, and every frame of a run without an odometer, are left
    as they are (their z is unknown).
    """
    odometry_mm = odometry_mm or {}
    posed = [k for k, (f, c) in enumerate(zip(frames, choices, strict=True))
             if f.fit.ok and c.chosen is not None and f.index in odometry_mm]
    out = list(frames)
    for n, k in enumerate(posed):
        lo, hi = posed[max(n - 1, 0)], posed[min(n + 1, len(posed) - 1)]
        found = _slope(*(_ring(frames[m], choices[m], odometry_mm) for m in (lo, hi)))
        if found is None:
            continue
        slope, change = found
        frame, chosen = frames[k], choices[k].chosen
        h = frame.fit.hypotheses[chosen]
        spread = sloping_wall_spread(slope, h.radius_mm, h.pose, plane_distance_mm)
        spread *= min(1.0, change / spread[2]) if spread[2] > 0 else 1.0
        stated = h.stated_std
        widened = {key: math.hypot(stated.get(key, 0.0), float(s))
                   for key, s in zip(PARAMS[:4], spread, strict=True)}
        hyps = list(frame.fit.hypotheses)
        hyps[chosen] = replace(h, std_override={**h.std_override, **widened})
        frame = replace(frame, fit=replace(frame.fit, hypotheses=tuple(hyps)))
        if spread[2] > stated.get("dx_mm", 0.0):   # more than the ring's own sigma
            frame = frame.with_warning(SLOPING_WALL_WARNING.format(
                slope=slope, bias=spread[2], tilt=math.degrees(spread[0])))
        out[k] = frame
    return out


def _ring(frame: FramePose, choice: Choice, odometry_mm: Mapping[int, float]
          ) -> tuple[float, float, float]:
    """(z, radius, radius sigma) of a frame's chosen ring."""
    h: Hypothesis = frame.fit.hypotheses[choice.chosen]
    return odometry_mm[frame.index], h.radius_mm, h.stated_std.get("radius_mm", math.nan)


def _slope(before: tuple[float, float, float], after: tuple[float, float, float]
           ) -> tuple[float, float] | None:
    """The wall's slope (mm of radius per mm of z) between two rings and their radius
    change (mm), or None where their radii do not differ significantly or their z do
    not."""
    dz, dr = abs(after[0] - before[0]), abs(after[1] - before[1])
    sigma = math.hypot(before[2], after[2])
    if dz <= 0 or not np.isfinite(sigma) or dr <= SLOPE_SIGMAS * sigma:
        return None
    return dr / dz, dr
