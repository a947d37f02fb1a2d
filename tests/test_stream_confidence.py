"""Confidence while PatchMatch runs (workbench/rerun/confidence.py): recorded for every view at several iterations
and levels, off without a viewer unless asked, and the engine's maps bit-identical with or without it."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SAMPLES

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import PipelineOptions, patchmatch_views
from engine.scene import load_scene
from workbench.rerun.options import DEFAULT_CONFIDENCE_EVERY, StreamOptions
from workbench.rerun.recording import Recording
from workbench.rerun.stream import entity_name

pytestmark = pytest.mark.timeout(900)


def test_a_short_fast_run_records_confidence_for_every_view_at_several_iterations(tmp_path):
    """Two levels, one iteration per pass, scored every iteration: each view's confidence, counter and labels at its
    4 iterations, at the level's size (80x60, then 160x120), and its ROC-AUC rises as PatchMatch converges."""
    from rerun.chunk import RrdReader
    from test_cli import deepc

    out = tmp_path / "out"
    result = deepc("run", SAMPLES / "tiny", "--out", out, "--headless", "--record", "--pipeline", "fast",
                   "--iterations", "1", "--levels", "2", "--geom-passes", "1", "--stream-confidence-every", "1",
                   timeout=800)
    assert result.returncode == 0, result.stderr[-2000:]
    store = RrdReader(str(out / "recording.rrd")).stream().collect()
    first_auc, last_auc = [], []
    for view in load_scene(SAMPLES / "tiny").views:
        base = entity_name(view.index, view.name)
        for kind in ("confidence", "counter", "label"):
            table = store.reader(index="view_iteration", contents=f"/maps/{base}/{kind}").to_arrow_table()
            assert set(table["view_iteration"].to_pylist()) == {0, 1, 2, 3}, (base, kind)
        table = store.reader(index="view_iteration", contents=f"/maps/{base}/confidence").to_arrow_table()
        sizes = {(t, f[0]["width"], f[0]["height"]) for t, f in
                 zip(table["view_iteration"].to_pylist(),
                     table[f"/maps/{base}/confidence:SegmentationImage:format"].to_pylist(), strict=True)}
        assert {(0, 80, 60), (1, 80, 60), (2, 160, 120), (3, 160, 120)} <= sizes
        table = store.reader(index="view_iteration", contents=f"/stats/{base}/confidence_auc").to_arrow_table()
        auc = [cell[0] for cell in table[f"/stats/{base}/confidence_auc:Scalars:scalars"].to_pylist()]
        assert len(auc) == 4 and all(50 <= a <= 100 for a in auc)
        first_auc.append(auc[0])
        last_auc.append(auc[-1])
    assert np.mean(last_auc) > np.mean(first_auc)


def test_scoring_is_off_without_a_viewer_and_leaves_the_maps_bit_identical(tmp_path):
    from workbench.rerun.run_recording import open_run_recording

    assert StreamOptions().confidence_k(live=True) == DEFAULT_CONFIDENCE_EVERY
    assert StreamOptions().confidence_k(live=False) == 0  # --headless --record
    assert StreamOptions(confidence_every=0).confidence_k(live=True) == 0
    scene = load_scene(SAMPLES / "tiny")
    options = PipelineOptions(patchmatch=PatchMatchOptions(iterations=1, levels=2, geom_passes=1))
    headless = open_run_recording(str(tmp_path / "headless.rrd"), scene, options, StreamOptions())
    assert headless.stream.companions == []
    headless.abandon()
    recording = open_run_recording(str(tmp_path / "run.rrd"), scene, options, StreamOptions(confidence_every=2))
    live = recording.stream.companions[0]
    plain = run_patchmatch(patchmatch_views(scene), options.patchmatch)
    streamed = run_patchmatch(patchmatch_views(scene), options.patchmatch, observer=recording.stream)
    recording.finish()
    assert live.computed == len(scene.views) * 2  # 4 iterations per view, every 2nd scored
    for a, b in zip(plain, streamed, strict=True):
        for field in ("depth", "normal", "cost", "selected_views"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_sources_at_another_level_are_resampled_and_views_without_maps_confirm_nothing(tmp_path):
    from test_stream import _stream

    from workbench.rerun.confidence import LiveConfidence

    recording = Recording(tmp_path / "run.rrd")
    stream = _stream(recording.rec)
    with pytest.raises(ValueError, match="every"):
        LiveConfidence(stream, 0, model=object())
    live = LiveConfidence(stream, 1, model=object())  # the network is not used here
    assert not live.source_depth(1, (12, 16)).any()
    coarse = np.arange(1, 49, dtype=np.float32).reshape(6, 8)
    live._latest[1] = coarse
    fine = live.source_depth(1, (12, 16))
    assert fine.shape == (12, 16)
    assert np.array_equal(fine[::2, ::2], coarse) and np.array_equal(fine[1::2, 1::2], coarse)  # nearest
    assert live.source_depth(1, (6, 8)) is coarse
    recording.abandon()
