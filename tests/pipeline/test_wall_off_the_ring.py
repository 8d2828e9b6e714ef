"""A strip that reaches wall of another radius than its ring's (a reducer, a long dent)
is warned: each strip is unwrapped onto its own ring's section (pipeline/run.py)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from pipestitch.io.dataset import open_dataset
from pipestitch.pipeline.posing import estimate_poses
from pipestitch.pipeline.run import _wall_off_the_ring


@pytest.fixture(scope="module")
def posed(simulate_small, tmp_path_factory):
    root = simulate_small(tmp_path_factory.mktemp("ring") / "ds", "--pairs", "6", "--seed", "1")
    return estimate_poses(open_dataset(root), show_progress=False)


def _widened(frames, choices, index: int, factor: float):
    """The frames with frame ``index``'s chosen ring radius times ``factor``."""
    out = list(frames)
    k, c = out[index], choices[index]
    hyps = list(k.fit.hypotheses)
    hyps[c.chosen] = replace(hyps[c.chosen], radius_mm=hyps[c.chosen].radius_mm * factor)
    out[index] = replace(k, fit=replace(k.fit, hypotheses=tuple(hyps)))
    return out


def test_strips_reaching_a_wider_wall_are_warned(posed) -> None:
    frames, choices = posed
    z = {f.index: 5.0 * f.index for f in frames}     # rings at z + 16 mm
    window = (-14.0, 34.0)                           # each strip about its camera's z
    assert not any(f.warning for f in _wall_off_the_ring(frames, choices, z, window, 16.0, 1.0,
                                                            set()))
    # frame 5's ring (z 41 mm) 3 % wider: the strips reaching z 41 mm are frames 2-4
    # (camera z 10-20 mm) and frame 5 itself sees the others 3 % narrower
    wider = _widened(frames, choices, 5, 1.03)
    warned = _wall_off_the_ring(wider, choices, z, window, 16.0, 1.0, set())
    assert [f.index for f in warned if "strip lies where" in f.warning] == [2, 3, 4, 5]
    assert "+3.0 %" in warned[2].warning and "-2.9 %" in warned[5].warning
    # within the tolerance: nothing
    small = _wall_off_the_ring(_widened(frames, choices, 5, 1.005), choices, z, window, 16.0,
                               1.0, set())
    assert not any(f.warning for f in small)
    # strips unwrapped onto the wall the rings measured (mosaic/wall_profile.py): not warned
    profiled = _wall_off_the_ring(wider, choices, z, window, 16.0, 1.0, {2, 3})
    assert [f.index for f in profiled if "strip lies where" in f.warning] == [4, 5]
