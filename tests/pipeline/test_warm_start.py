"""A run whose first frames were decoded ahead writes exactly what a run without does."""

from __future__ import annotations

import gc
from pathlib import Path

import pytest

from pipestitch.io import ahead
from pipestitch.pipeline.run import run_dataset
from pipestitch.pipeline.warm_start import decode_ahead, loading_stages


def test_a_run_with_frames_decoded_ahead_writes_the_same_outputs(tmp_path: Path,
                                                                  simulate_small,
                                                                  monkeypatch) -> None:
    ds = simulate_small(tmp_path / "ds", "--pairs", "6", "--seed", "2")
    run_dataset(ds, tmp_path / "plain", show_progress=False)
    taken = []
    original = ahead.DecodeAhead.take

    def counted(self, path):
        got = original(self, path)
        taken.append(got is not None)
        return got

    monkeypatch.setattr(ahead.DecodeAhead, "take", counted)
    with decode_ahead(ds) as frames:
        frames._thread.join(30)   # every frame decoded before the run reads one
        assert not frames.running
        run_dataset(ds, tmp_path / "ahead", show_progress=False)
    assert sum(taken) == 12   # each of the 6 pairs' two frames taken once
    for name in ("poses.csv", "profile.csv", "defects.csv", "mosaic.png"):
        assert (tmp_path / "ahead" / name).read_bytes() == (tmp_path / "plain" / name
                                                            ).read_bytes(), name


def test_loading_stages_holds_the_collector_off_and_freezes_what_it_made() -> None:
    """Inside: no collection; after: the collector as it was, and the objects the block
    made (with everything else alive) out of later collections."""
    was = gc.isenabled()
    gc.enable()
    try:
        before = gc.get_freeze_count()
        with loading_stages():
            assert not gc.isenabled()
            made = [{"k": [i]} for i in range(1000)]   # long-lived, as a module's tables
        assert gc.isenabled()
        assert gc.get_freeze_count() >= before + len(made)
        with pytest.raises(RuntimeError), loading_stages():
            raise RuntimeError("an import failed")
        assert gc.isenabled()   # the collector back on when the block fails
        gc.disable()
        with loading_stages():
            pass
        assert not gc.isenabled()   # and left off when it was off
    finally:
        gc.unfreeze()
        (gc.enable if was else gc.disable)()

