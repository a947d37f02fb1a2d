"""PatchMatch checkpoints: an interrupted run resumes from verified saved states to identical maps."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import SAMPLES

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.checkpoint import PatchMatchCheckpoint
from engine.run.pipeline import patchmatch_views
from engine.scene import SceneOptions, load_scene

OPTIONS = PatchMatchOptions(levels=2, geom_passes=1, iterations=1, seed=7)  # 4 passes of 5 views


@pytest.fixture(scope="module")
def views():
    return patchmatch_views(load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=96)))


@pytest.fixture(scope="module")
def reference(views):
    return run_patchmatch(views, OPTIONS)


class _Interrupt:
    """A progress callback that raises KeyboardInterrupt (like Ctrl+C) after ``after`` view-passes."""

    def __init__(self, after: int):
        self.after, self.calls = after, 0

    def __call__(self, description: str, done: int, total: int) -> None:
        if done == 0:  # a pass starting, not a view-pass done
            return
        self.calls += 1
        if self.calls == self.after:
            raise KeyboardInterrupt


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(x, k), getattr(y, k)) for x, y in zip(a, b, strict=True)
               for k in ("depth", "normal", "cost", "selected_views"))


def _interrupted(views, folder, after: int) -> None:
    with pytest.raises(KeyboardInterrupt):
        run_patchmatch(views, OPTIONS, progress=_Interrupt(after), checkpoint=PatchMatchCheckpoint(folder))


@pytest.mark.parametrize("after", [3, 13, 20])  # mid first pass, mid third pass, last view of the last pass
def test_resume_after_interruption_gives_identical_maps(views, reference, tmp_path, after):
    folder = tmp_path / ".deepc-resume"
    _interrupted(views, folder, after)
    checkpoint = PatchMatchCheckpoint(folder, resume=True)
    resumed = run_patchmatch(views, OPTIONS, checkpoint=checkpoint)
    assert _same(resumed, reference)
    assert checkpoint.stats.reused > 0 and checkpoint.stats.rejected == 0
    # the interrupted run had saved `after` view-passes: only the other ones were computed again
    assert checkpoint.stats.saved == 20 - after


def test_damaged_saved_state_is_recomputed_not_trusted(views, reference, tmp_path):
    folder = tmp_path / ".deepc-resume"
    _interrupted(views, folder, 13)
    saved = sorted(folder.glob("L*_P*/*.npz"))
    data = bytearray(saved[0].read_bytes())
    data[len(data) // 2] ^= 0x10
    saved[0].write_bytes(bytes(data))
    checkpoint = PatchMatchCheckpoint(folder, resume=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resumed = run_patchmatch(views, OPTIONS, checkpoint=checkpoint)
    assert _same(resumed, reference)
    assert checkpoint.stats.rejected == 1
    assert any("saved state unusable" in str(w.message) and "checksum" in str(w.message) for w in caught)


def test_states_of_other_options_are_not_reused(views, tmp_path):
    folder = tmp_path / ".deepc-resume"
    _interrupted(views, folder, 8)
    other = PatchMatchOptions(**{**OPTIONS.to_dict(), "seed": 8})
    checkpoint = PatchMatchCheckpoint(folder, resume=True)
    with pytest.warns(UserWarning, match="other inputs or options"):
        run_patchmatch(views, other, checkpoint=checkpoint)
    assert checkpoint.stats.reused == 0 and checkpoint.stats.saved == 20


def test_at_most_two_passes_are_kept_on_disk(views, tmp_path):
    folder = tmp_path / ".deepc-resume"
    _interrupted(views, folder, 18)
    assert sorted(p.name for p in folder.iterdir() if p.is_dir()) == ["L0_P0", "L0_P1"]


def test_idle_views_are_parked_in_the_checkpoint(views, reference, tmp_path):
    """With a checkpoint, a view between its passes holds only its depth (its normal, cost and selected views wait
    in the checkpoint): the same maps, about 20 B a pixel of every idle view less at the peak, no state counted
    as reused."""
    import tracemalloc

    def peak(checkpoint):
        tracemalloc.start()
        try:
            maps = run_patchmatch(views, OPTIONS, checkpoint=checkpoint)
            return maps, tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    plain, plain_peak = peak(None)
    checkpoint = PatchMatchCheckpoint(tmp_path / ".deepc-resume", resume=False)
    parked, parked_peak = peak(checkpoint)
    assert _same(plain, reference) and _same(parked, reference)
    assert checkpoint.stats.reused == 0
    pixels = sum(v.image_gray.size for v in views)
    largest = max(v.image_gray.size for v in views)
    assert plain_peak - parked_peak > 0.5 * 20 * (pixels - largest), (plain_peak, parked_peak)


def test_a_parked_state_that_cannot_be_read_back_is_one_clear_error(views, tmp_path, monkeypatch):
    from engine.core.errors import DeepCError

    checkpoint = PatchMatchCheckpoint(tmp_path / ".deepc-resume", resume=False)
    monkeypatch.setattr(checkpoint, "load", lambda *args, **kwargs: None)
    with pytest.raises(DeepCError, match="could not be read back"):
        run_patchmatch(views, OPTIONS, checkpoint=checkpoint)
