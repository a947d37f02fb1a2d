"""The rerun stream: events in, a readable .rrd with the expected entities and iterations out."""

from __future__ import annotations

import numpy as np
import pytest

from engine.camera import Camera
from engine.observer import IterationEvent
from workbench.recording import Recording
from workbench.stream import RerunStream, StreamOptions, entity_name, selected_views_list


def _events(n_views: int, iterations: int, shape=(12, 16)):
    rng = np.random.default_rng(0)
    step = 0
    for it in range(iterations):
        for v in range(n_views):
            depth = rng.uniform(1, 2, shape).astype(np.float32)
            depth[0, :] = 0
            normal = np.zeros(shape + (3,), np.float32)
            normal[..., 2] = -1
            yield IterationEvent(v, f"img/{v}.png", 0, "photometric", 0, it, step, depth, normal,
                                 rng.uniform(0, 2, shape).astype(np.float32),
                                 rng.integers(0, 8, shape).astype(np.uint32), 0.01)
            step += 1


def _stream(rec, n_views=2, options=None, gt=None):
    cam = Camera.from_params(16, 12, 20.0, 20.0, 8.0, 6.0)
    views = [(f"img/{v}.png", cam, np.zeros((12, 16, 3), np.float32), [1 - v]) for v in range(n_views)]
    return RerunStream(rec, views, gt, options, pass_iterations=lambda p: 4)


def _read(path):
    from rerun.chunk import RrdReader
    return RrdReader(str(path)).stream().collect()


def test_recording_holds_maps_stats_and_every_iteration(tmp_path):
    path = tmp_path / "run.rrd"
    recording = Recording(path)
    gt = [np.full((12, 16), 1.5, np.float32), None]
    stream = _stream(recording.rec, gt=gt)
    for event in _events(2, 4):
        stream.on_iteration(event)
    recording.finish()
    assert path.is_file() and not list(tmp_path.glob(".*.tmp"))
    store = _read(path)
    base = entity_name(0, "img/0.png")
    table = store.reader(index="iteration", contents=f"/maps/{base}/**").to_arrow_table()
    assert table.num_rows == 4
    fmt = table[f"/maps/{base}/depth:DepthImage:format"][2].as_py()[0]
    buf = table[f"/maps/{base}/depth:DepthImage:buffer"][2].as_py()[0]
    raw = bytes(buf)
    assert len(raw) == 2 * 12 * 16  # logged as float16 to keep recordings small
    depth = np.frombuffer(raw, np.float16).reshape(fmt["height"], fmt["width"])
    assert depth[0].max() == 0 and 1 <= depth[1:].min() <= depth.max() <= 2
    summary = str(store.summary())
    for kind in ("normal", "cost", "selected_count", "selected_views", "error"):
        assert f"/maps/{base}/{kind}" in summary
    assert f"/maps/{entity_name(1, 'img/1.png')}/error" not in summary  # no GT for view 1
    for stat in ("mean_cost", "changed_pct", "within_1pct", "level", "pass", "seconds"):
        assert f"/stats/{base}/{stat}" in summary
    assert "/world/cameras/" in summary


def test_thinning_keeps_the_last_iteration_of_each_pass_and_one_view(tmp_path):
    recording = Recording(tmp_path / "thin.rrd")
    stream = _stream(recording.rec, options=StreamOptions(every=3, view=1, max_size=8))
    for event in _events(2, 4):
        stream.on_iteration(event)
    recording.finish()
    assert stream.logged_steps == 2  # iterations 0 and 3 (last of the pass) of view 1
    # the raw bitmask is logged only at the end of a pass
    store = _read(tmp_path / "thin.rrd")
    base = entity_name(1, "img/1.png")
    table = store.reader(index="iteration", contents=f"/maps/{base}/depth").to_arrow_table()
    assert table.num_rows == 2
    fmt = table[f"/maps/{base}/depth:DepthImage:format"][0].as_py()[0]
    assert max(fmt["width"], fmt["height"]) <= 8
    assert f"/maps/{entity_name(0, 'img/0.png')}/depth" not in str(store.summary())


def test_abandoned_recording_leaves_nothing(tmp_path):
    recording = Recording(tmp_path / "x.rrd")
    recording.abandon()
    assert list(tmp_path.iterdir()) == []


def test_selected_views_mask_decodes_to_view_indices():
    assert selected_views_list(0b1011, [7, 3, 9, 4]) == [7, 3, 4]
    assert selected_views_list(0, [1, 2]) == []


def test_stream_options_are_validated():
    from engine.errors import OptionsError
    with pytest.raises(OptionsError, match="every"):
        StreamOptions(every=0).validate()
