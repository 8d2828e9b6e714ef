"""The pose step's photometric comparisons count only where registration linked the two
frames: consecutive LED frames that share too little wall (a large step without an
odometer) compare noise, and their choices are made again without them."""

from __future__ import annotations

import re
from types import SimpleNamespace

import pytest

from pipestitch.io.dataset import open_dataset
from pipestitch.mosaic.register import Link
from pipestitch.pipeline.posing import estimate_poses
from pipestitch.pipeline.run import _unconfirmed_comparisons


@pytest.fixture(scope="module")
def compared(simulate_small, tmp_path_factory):
    """A corroded run without a declared body: every mirror decided by the comparisons."""
    root = simulate_small(tmp_path_factory.mktemp("cmp") / "ds", "--scenario", "corrosion",
                          "--pairs", "8", "--seed", "3")
    toml = root / "probe.toml"
    toml.write_text(re.sub(r"\[probe\][^\[]*", "", toml.read_text()))
    frames, choices = estimate_poses(open_dataset(root), show_progress=False)
    assert sum(c.reason == "photometric" for c in choices) >= 6
    assert all(f.compared is not None for f in frames[1:])
    return frames, choices


def _result(frames, unlinked: set[int], registered: set[int]) -> SimpleNamespace:
    links = [Link(i, i + 1, 5.0, 0.0, 0.5, 0.02, 0.02) for i in range(len(frames) - 1)
             if i + 1 not in unlinked]
    return SimpleNamespace(links=links, views=dict.fromkeys(registered))


def test_linked_comparisons_keep_their_choices(compared) -> None:
    frames, choices = compared
    everything = _result(frames, set(), set(range(len(frames))))
    assert _unconfirmed_comparisons(frames, choices, everything, None) == choices


def test_comparisons_registration_never_linked_decide_nothing(compared) -> None:
    frames, choices = compared
    # no frame linked to its predecessor: no comparison is evidence any more
    none = _result(frames, set(range(1, len(frames))), set())
    again = _unconfirmed_comparisons(frames, choices, none, None)
    assert all(c.ambiguous for c in again)
    # the same, the frames registered: hypotheses kept (unwrapped so), flagged
    placed = _result(frames, set(range(1, len(frames))), set(range(len(frames))))
    kept = _unconfirmed_comparisons(frames, choices, placed, None)
    assert [c.chosen for c in kept] == [c.chosen for c in choices]
    assert {c.reason for c in kept} == {"photometric-unconfirmed"}
