"""The ring store: ring points moved out of memory into a temporary file and read back."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from pipestitch.io.dataset import open_dataset
from pipestitch.pipeline.posing import estimate_poses
from pipestitch.pipeline.ring_store import RingStore, StoredRing
from pipestitch.pipeline.run import _compact_ring, _without_rings
from pipestitch.pipeline.stitching import FrameView, _refit_section
from pipestitch.pose.fit import LaserPlane, RingPoints


def _ring(n: int, seed: int) -> RingPoints:
    rng = np.random.default_rng(seed)
    uv = rng.normal(0, 30, (n, 2)).astype(np.float32)
    return RingPoints(uv, uv + 500, LaserPlane.of(16.0, None))


def test_stored_points_read_back_exactly_and_give_the_same_probe_points() -> None:
    with RingStore() as store:
        rings = [_ring(n, n) for n in (720, 1, 357)]
        handles = [store.put(r) for r in rings]
        assert store.nbytes == sum(r.uv.nbytes for r in rings)
        for ring, handle in zip(rings, handles, strict=True):
            assert isinstance(handle, StoredRing) and handle.n_points == len(ring.uv)
            np.testing.assert_array_equal(handle.uv, ring.uv)
            np.testing.assert_array_equal(handle.points_mm, ring.points_mm)
            assert handle.pixels.shape == (0, 2) and handle.plane is ring.plane
        assert store.put(None) is None


def test_puts_and_reads_from_several_threads_do_not_mix_up_frames() -> None:
    def work(k: int) -> dict[int, StoredRing]:
        out = {}
        for j in range(20):
            out[k * 100 + j] = store.put(_ring(50 + j, k * 100 + j))
            out[k * 100 + j].uv  # noqa: B018 (a read between writes)
        return out

    with RingStore() as store, ThreadPoolExecutor(4) as pool:
        handles = {key: h for part in pool.map(work, range(4)) for key, h in part.items()}
        assert len(handles) == 80   # map re-raises a thread's exception here
        for key, handle in handles.items():
            np.testing.assert_array_equal(handle.uv, _ring(50 + key % 100, key).uv)


def test_stored_points_are_read_only_float32_and_probe_points_float64() -> None:
    with RingStore() as store:
        handle = store.put(_ring(30, 1))
        assert handle.uv.dtype == np.float32 and not handle.uv.flags.writeable
        assert handle.points_mm.dtype == np.float64 and handle.points_mm.shape == (30, 3)


def test_a_closed_store_says_so_when_read() -> None:
    store = RingStore()
    handle = store.put(_ring(10, 0))
    store.close()
    with pytest.raises(RuntimeError, match="closed"):
        handle.uv  # noqa: B018


def test_without_a_usable_temporary_folder_the_points_stay_in_memory(tmp_path) -> None:
    with RingStore(directory=str(tmp_path / "missing")) as store:
        assert "TMPDIR" in store.problem
        ring = _ring(40, 2)
        kept = store.put(ring)
        assert isinstance(kept, RingPoints) and kept.pixels.shape == (0, 2)
        np.testing.assert_array_equal(kept.uv, ring.uv)


def test_a_failing_write_keeps_the_earlier_handles_and_the_rest_in_memory() -> None:
    with RingStore() as store:
        first = store.put(_ring(20, 3))

        class Full:
            def __init__(self, f) -> None:
                self._f = f

            def write(self, data) -> None:
                raise OSError(28, "No space left on device")

            def __getattr__(self, name):
                return getattr(self._f, name)

        store._file = Full(store._file)
        later = store.put(_ring(20, 4))
        assert "No space left" in store.problem and isinstance(later, RingPoints)
        np.testing.assert_array_equal(first.uv, _ring(20, 3).uv)
        np.testing.assert_array_equal(later.uv, _ring(20, 4).uv)


def test_the_pose_pass_moves_every_ring_into_the_store_unchanged(tmp_path,
                                                                 simulate_small) -> None:
    """Same fits with and without the store; with it, no frame holds its ring in memory
    and each stored ring reads back as the fit's own uv; the run then drops them."""
    root = simulate_small(tmp_path / "ds", "--pairs", "3", "--seed", "2")
    dataset = open_dataset(root)
    kept, kept_choices = estimate_poses(dataset, show_progress=False, workers=1)
    with RingStore() as store:
        moved, choices = estimate_poses(dataset, show_progress=False, workers=1, rings=store)
        assert [c.chosen for c in choices] == [c.chosen for c in kept_choices]
        assert sum(f.fit.ok for f in moved) == 3
        for a, b in zip(kept, moved, strict=True):
            assert b.fit.ring is None and isinstance(b.stored_ring, StoredRing)
            assert b.fit.hypotheses == a.fit.hypotheses
            np.testing.assert_array_equal(b.ring.uv, a.fit.ring.uv)
            assert _compact_ring(b.ring) is b.stored_ring
        assert all(f.ring is None for f in _without_rings(moved))
        # the consumer, the section refit, gets the same section from either
        for a, b in zip(kept, moved, strict=True):
            h = a.fit.hypotheses[0]
            refits = [_refit_section(FrameView(h.pose, h.pipe_section, refined=True, ring=r))
                      for r in (_compact_ring(a.ring), b.ring)]
            assert refits[0].measured is not None
            assert refits[0].measured.section == refits[1].measured.section
            assert refits[0].pose == refits[1].pose
    dropped, _ = estimate_poses(dataset, show_progress=False, workers=1, drop_rings=True)
    assert [f.ring for f in dropped] == [None] * 3
    assert [f.fit.hypotheses for f in dropped] == [f.fit.hypotheses for f in kept]
