"""``deepc replay A.rrd --compare B.rrd``: both recordings merged into one under ``a/`` and ``b/``, each with its own
maps, and a layout that sets each map of A beside B's."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_cli import _one_line_error, deepc
from test_replay_browser import blueprint_titles
from test_stream import _depth, _events, _read, _stream

from engine.core.errors import DeepCError
from workbench.rerun.recording import Recording
from workbench.rerun.replay import compare_files
from workbench.rerun.stream import entity_name

VIEW = entity_name(0, "img/0.png")


def _record(path, scale: float = 1.0, n_views: int = 2):
    """A recording of two views' iterations; ``scale`` multiplies every depth (B: a run that is off)."""
    recording = Recording(path)
    stream = _stream(recording.rec, n_views=n_views, gt=[np.full((12, 16), 1.5, np.float32)] + [None] * (n_views - 1))
    for event in _events(n_views, 3):
        stream.on_iteration(dataclasses.replace(event, depth=event.depth * np.float32(scale)))
    recording.finish()
    return path


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay_compare")
    return _record(root / "a.rrd"), _record(root / "b.rrd", scale=1.25)


def test_the_merged_recording_holds_both_runs_maps_of_a_view_under_a_and_b(pair, tmp_path):
    merged, blueprint = compare_files(*pair, tmp_path, view="1")
    store = _read(merged)
    summary = str(store.summary())
    for side in ("a", "b"):
        for kind in ("depth", "error", "cost"):
            assert f"/{side}/maps/{VIEW}/{kind}" in summary
        assert f"/{side}/world/cameras/{VIEW}" in summary
    assert f"\n/maps/{VIEW}" not in "\n" + summary  # nothing is left outside a/ and b/
    tables = {side: store.reader(index="iteration", contents=f"/{side}/maps/{VIEW}/**").to_arrow_table()
              for side in ("a", "b")}
    a, b = (_side_depth(tables[side], side, 2) for side in ("a", "b"))
    valid = a > 0
    assert valid.sum() > 100
    np.testing.assert_allclose(b[valid] / a[valid], 1.25, rtol=2e-3)  # B's own depths, not A's again
    titles = blueprint_titles(blueprint)
    assert "A · 000 · depth (m)" in titles and "B · 000 · depth (m)" in titles
    assert "img/1.png (view 1)" in titles  # a tab per view, the one asked for among them


def _side_depth(table, side: str, row: int) -> np.ndarray:
    """The depth map of VIEW that ``side``'s recording logged in ``row``, in model units."""
    renamed = table.rename_columns([c.replace(f"/{side}/maps/", "/maps/") for c in table.column_names])
    return _depth(renamed, VIEW, row)


def test_recordings_without_a_view_in_common_are_refused(pair, tmp_path):
    empty = Recording(tmp_path / "empty.rrd")
    empty.finish()
    with pytest.raises(DeepCError, match="no view's maps in common"):
        compare_files(pair[0], tmp_path / "empty.rrd", tmp_path)


def test_replay_compare_with_a_layout_or_a_missing_file_is_one_line(pair, tmp_path):
    _one_line_error(deepc("replay", pair[0], "--compare", pair[1], "--layout", "pipelines", "--web", "--port", "0"),
                    "--layout")
    _one_line_error(deepc("replay", pair[0], "--compare", tmp_path / "nowhere.rrd", "--web", "--port", "0"),
                    "nowhere.rrd")
