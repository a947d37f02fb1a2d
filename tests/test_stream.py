"""The rerun stream: events in, a readable .rrd with the expected entities and iterations out."""

from __future__ import annotations

import io

import numpy as np
import pytest

from engine.core.camera import Camera
from engine.core.observer import IterationEvent
from workbench.rerun.recording import Recording
from workbench.rerun.stream import RerunStream, StreamOptions, entity_name, selected_views_list


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


def _depth(table, base: str, row: int) -> np.ndarray:
    """The depth map logged in ``row`` of ``table`` (a 16-bit PNG and its steps per model unit), in model units."""
    from PIL import Image

    blob = bytes(table[f"/maps/{base}/depth:EncodedDepthImage:blob"][row].as_py()[0])
    meter = table[f"/maps/{base}/depth:EncodedDepthImage:meter"][row].as_py()[0]
    return np.asarray(Image.open(io.BytesIO(blob))).astype(np.float64) / meter


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
    depth = _depth(table, base, 2)  # a 16-bit PNG to keep recordings small, read back in model units
    assert depth.shape == (12, 16) and depth[0].max() == 0 and 1 <= depth[1:].min() <= depth.max() <= 2
    # cost hovers as "matching cost 0.37 ..." (class-coded in 0.01 steps), no depth = class 0
    cost = np.frombuffer(bytes(table[f"/maps/{base}/cost:SegmentationImage:buffer"][2].as_py()[0]), np.uint8)
    cost = cost.reshape(12, 16)
    assert cost[0].max() == 0 and 1 <= cost[1:].min() and cost.max() <= 201
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
    assert max(_depth(table, base, 0).shape) <= 8
    assert f"/maps/{entity_name(0, 'img/0.png')}/depth" not in str(store.summary())


def test_one_view_scrubs_on_its_own_timeline_with_gt_error_at_every_level(tmp_path):
    """view_iteration counts one view's iterations (views interleave on the global step); a coarser pyramid level
    still gets an error map (GT resampled); the error map hovers as a relative error class, not as 'Depth'."""
    path = tmp_path / "levels.rrd"
    recording = Recording(path)
    gt = [np.full((12, 16), 1.5, np.float32), None]
    stream = _stream(recording.rec, gt=gt)
    rng = np.random.default_rng(1)
    step = 0
    for level, shape in ((1, (6, 8)), (0, (12, 16))):
        for it in range(2):
            for v in range(2):
                depth = np.full(shape, 1.5345, np.float32)  # 2.3 % too far
                normal = np.zeros(shape + (3,), np.float32)
                stream.on_iteration(IterationEvent(v, f"img/{v}.png", level, "photometric", 0, it, step, depth, normal,
                                                   rng.uniform(0, 2, shape).astype(np.float32),
                                                   np.zeros(shape, np.uint32), 0.01))
                step += 1
    recording.finish()
    store = _read(path)
    base = entity_name(0, "img/0.png")
    table = store.reader(index="view_iteration", contents=f"/maps/{base}/depth").to_arrow_table()
    assert table["view_iteration"].to_pylist() == [0, 1, 2, 3]
    assert table["iteration"].to_pylist() == [0, 2, 4, 6]  # the global step interleaves the views
    assert table["pass"].to_pylist() == [0, 0, 1, 1]  # level 1's pass, then level 0's
    # a hover's position times pixel_scale is the full-resolution pixel the viewer's inspector takes
    scale = store.reader(index="view_iteration", contents=f"/stats/{base}/pixel_scale").to_arrow_table()
    assert [row[0] for row in scale[f"/stats/{base}/pixel_scale:Scalars:scalars"].to_pylist()] == [2, 2, 1, 1]
    error = store.reader(index="view_iteration", contents=f"/maps/{base}/error").to_arrow_table()
    assert error.num_rows == 4  # the coarse level too
    fmt = error[f"/maps/{base}/error:SegmentationImage:format"][0].as_py()[0]
    ids = np.frombuffer(bytes(error[f"/maps/{base}/error:SegmentationImage:buffer"][0].as_py()[0]), np.uint8)
    assert (fmt["width"], fmt["height"]) == (8, 6) and set(ids) == {10}  # class 10 = 2.25-2.50 %
    summary = str(store.summary())
    assert any(line.startswith(f"/maps/{base}/error ") and "AnnotationContext" in line for line in summary.splitlines())
    from workbench.rerun.legends import error_context
    labels = {c["class_id"]: c["class_description"]["info"]["label"]
              for c in error_context().context.as_arrow_array().to_pylist()[0]}
    assert labels[10] == "relative error 2.25-2.50 %" and labels[0].startswith("no data")


def test_stage_maps_sit_at_each_views_last_iteration_with_labels(tmp_path):
    """Counter after PatchMatch and confidence + GT labels after the confidence stage, at the view's end."""
    path = tmp_path / "stages.rrd"
    recording = Recording(path)
    gt = [np.full((12, 16), 1.5, np.float32), None]
    cams = [Camera.from_params(16, 12, 20.0, 20.0, 8.0, 6.0, t=np.array([0.3 * v, 0.0, 0.0])) for v in range(2)]
    views = [(f"img/{v}.png", cams[v], np.zeros((12, 16, 3), np.float32), [1 - v]) for v in range(2)]
    stream = RerunStream(recording.rec, views, gt, pass_iterations=lambda p: 4)
    stream.set_depth_ranges([(1.0, 10.0), (1.0, 10.0)])
    for event in _events(2, 4):
        stream.on_iteration(event)
    depth = np.full((12, 16), 1.5, np.float32)  # the GT depth: inliers
    depth[:, :4] = 6.0  # 3 px off in the other view: outliers
    depth[0, 0] = 0
    stream.on_stage("patchmatch", counter=[np.full((12, 16), 3.0, np.float32)] * 2)
    stream.on_stage("confidence", confidence=[np.full((12, 16), 0.25, np.float32)] * 2, depth=[depth, depth])
    recording.finish()
    store = _read(path)
    summary = str(store.summary())
    base, other = entity_name(0, "img/0.png"), entity_name(1, "img/1.png")
    for kind in ("counter", "confidence", "label"):
        table = store.reader(index="view_iteration", contents=f"/maps/{base}/{kind}").to_arrow_table()
        assert table["view_iteration"].to_pylist() == [3], kind  # the view's last iteration
    assert f"/maps/{other}/confidence" in summary and f"/maps/{other}/label" not in summary  # no GT for view 1
    table = store.reader(index="view_iteration", contents=f"/maps/{base}/label").to_arrow_table()
    ids = np.frombuffer(bytes(table[f"/maps/{base}/label:SegmentationImage:buffer"][0].as_py()[0]), np.uint8)
    ids = ids.reshape(12, 16)
    assert ids[0, 0] == 0 and ids[5, 0] == 1 and ids[5, 10] == 2  # unlabeled, outlier, inlier
    assert "/legend/error" in summary and "\n/legend rows" in summary


def test_abandoned_recording_leaves_nothing(tmp_path):
    recording = Recording(tmp_path / "x.rrd")
    recording.abandon()
    assert list(tmp_path.iterdir()) == []


def test_selected_views_mask_decodes_to_view_indices():
    assert selected_views_list(0b1011, [7, 3, 9, 4]) == [7, 3, 4]
    assert selected_views_list(0, [1, 2]) == []


def test_stream_options_are_validated():
    from engine.core.errors import OptionsError
    with pytest.raises(OptionsError, match="every"):
        StreamOptions(every=0).validate()


def test_depth_maps_are_logged_losslessly_to_a_step_of_their_range():
    """PNG depth: back in model units within half a step, a step at most 2.5 × the farther of the range and the
    map's maximum / DEPTH_STEPS (so a depth beyond the range is not cut), 'no depth' stays 0 and a valid depth
    never becomes 0."""
    from PIL import Image

    from workbench.rerun.stream import DEPTH_STEPS, depth_image

    depth = np.random.default_rng(0).uniform(1, 9, (12, 16))
    depth[0] = 0
    depth[1, 0] = 1e-9  # valid, far below one step
    image = depth_image(depth, (1.0, 8.0))
    blob = bytes(image.blob.as_arrow_array().to_pylist()[0])
    back = np.asarray(Image.open(io.BytesIO(blob))).astype(np.float64) / image.meter.as_arrow_array().to_pylist()[0]
    step = 1 / image.meter.as_arrow_array().to_pylist()[0]
    assert step <= 2.5 * depth.max() / DEPTH_STEPS
    assert np.abs(back - depth)[2:].max() <= 0.5 * step * (1 + 1e-6)
    assert (back[0] == 0).all() and (back[1:] > 0).all()


def test_depth_hover_reads_metres_in_a_few_digits_and_the_legend_says_what_position_counts():
    """Rerun 0.41's hover prints steps / meter with every digit and no unit ("Depth 7.031 013 431 013 43", seen in
    chromium): the meter is a round number, so the hover prints a short decimal of metres, the panel title names
    the unit, and the legend says which pixels a hover's position counts."""
    from PIL import Image

    from layouts import Contents, map_panel
    from workbench.rerun.legends import legend_markdown
    from workbench.rerun.stream import depth_image

    for far in (0.7, 8.33, 41.0, 260.0):
        depth = np.random.default_rng(1).uniform(far / 4, far, (12, 16))
        image = depth_image(depth, (far / 5, far))
        meter = image.meter.as_arrow_array().to_pylist()[0]
        blob = bytes(image.blob.as_arrow_array().to_pylist()[0])
        steps = np.asarray(Image.open(io.BytesIO(blob))).astype(np.float64)
        shown = [repr(float(v) / meter) for v in steps.ravel()[:50]]  # as rerun formats f64: shortest round trip
        assert max(len(text.split(".")[-1]) for text in shown) <= 4, (far, meter, shown[:3])
    view = entity_name(3, "img/3.png")
    assert map_panel(Contents([view]), view, "depth").name == "003 · depth (m)"
    legend = legend_markdown()
    assert "Hover position" in legend and "stats/<view>/pixel_scale" in legend and "depth in metres" in legend
