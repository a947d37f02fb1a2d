"""A recorded .rrd replays in the rerun web viewer (real chromium) with every layout, built per view."""

from __future__ import annotations

import io
import socket
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from engine.core.errors import DeepCError
from support.browser import rerun_crashed
from workbench.rerun.recording import Recording
from workbench.rerun.replay import WebViewer, layout_file, layout_files, recording_contents, recording_views
from workbench.rerun.stream import entity_name

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from test_stream import _events, _stream

    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    rec = Recording(path)
    stream = _stream(rec.rec, gt=[np.full((12, 16), 1.5, np.float32), None])  # GT for view 0 only
    for event in _events(2, 4):
        stream.on_iteration(event)
    rec.finish()
    return path


def blueprint_titles(rbl) -> list[str]:
    """The panel titles of a saved blueprint (what the viewer shows above each panel and on each tab)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rbl))
    store = reader.stream(store=reader.blueprints()[0]).collect()
    titles = []
    for prefix, archetype in (("/view/**", "ViewBlueprint"), ("/container/**", "ContainerBlueprint")):
        table = store.reader(index="blueprint", contents=prefix).to_arrow_table()
        for column in table.column_names:
            if column.endswith(f":{archetype}:display_name"):
                titles += [cell[0] for cell in table[column].to_pylist() if cell]
    return titles


def notes(path) -> dict[str, str]:
    """The text documents of a notes recording, by entity path."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    store = reader.stream(store=reader.recordings()[0]).collect()
    table = store.reader(index=None, contents="/**").to_arrow_table()
    return {column.split(":")[0]: table[column][0].as_py()[0] for column in table.column_names
            if column.endswith(":TextDocument:text")}


def test_recording_views_and_layouts(recording, tmp_path):
    assert recording_views(recording) == [entity_name(0, "img/0.png"), entity_name(1, "img/1.png")]
    for name in ("iterations", "pipelines", "confidence"):
        assert layout_file(recording, name, tmp_path).stat().st_size > 0
    with pytest.raises(DeepCError, match="unknown layout"):
        layout_file(recording, "nope", tmp_path)
    with pytest.raises(DeepCError, match=r"no view 'img/9.png' in the recording \(it holds img/0.png \(view 0\)"):
        layout_file(recording, "iterations", tmp_path, view="img/9.png")


def test_layouts_name_the_chosen_view_and_say_what_is_missing(recording, tmp_path):
    """--view by image name or index; every map panel is titled with the view; a map the recording lacks
    (view 1 has no GT, nothing has a counter) is a text panel saying why, not an empty panel."""
    contents = recording_contents(recording).contents
    assert {"view_iteration", "pass", "iteration"} <= contents.timelines
    for view in ("img/1.png", "1"):
        rbl, notes_rrd = layout_files(recording, "iterations", tmp_path, view=view)
        titles = blueprint_titles(rbl)
        assert "depth · img/1.png (view 1)" in titles and "cost · img/1.png (view 1)" in titles
        assert "error vs GT · img/1.png (view 1): not recorded" in titles
        assert not [t for t in titles if "view 0" in t]
    docs = notes(notes_rrd)
    assert "no GT depth" in docs[f"/missing/{entity_name(1, 'img/1.png')}/error"]
    assert f"/missing/{entity_name(0, 'img/0.png')}/error" not in docs  # view 0 has its error map
    assert "img/1.png (view 1)" in docs["/about"] and "view_iteration" in docs["/about"]
    # the confidence layout: a tab per view (not only the first 4), each with confidence, labels and error
    titles = blueprint_titles(layout_files(recording, "confidence", tmp_path, view="img/0.png")[0])
    for view in ("img/0.png (view 0)", "img/1.png (view 1)"):
        assert view in titles
        assert f"confidence · {view}: not recorded" in titles and f"GT labels · {view}: not recorded" in titles
    assert "error vs GT · img/0.png (view 0)" in titles


def test_bad_recordings_are_refused(tmp_path):
    (tmp_path / "x.rrd").write_bytes(b"not a recording")
    with pytest.raises(DeepCError, match="x.rrd"):
        recording_views(tmp_path / "x.rrd")
    with pytest.raises(DeepCError, match="not found"):
        WebViewer(tmp_path / "missing.rrd")


def test_replay_on_a_port_in_use_is_one_line(recording):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "workbench.cli", "replay", str(recording), "--web",
                                 "--port", str(port)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == (f"deepc: error: port {port} on 127.0.0.1 is in use (another viewer?): "
                                     "pass --port N, or --port 0 for any free port")
    assert "\x1b[" not in result.stderr + result.stdout


def _shot(browser_context, viewer) -> np.ndarray:
    page = browser_context.new_page()
    errors = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        page.goto(viewer.url + "&renderer=webgl")
        page.wait_for_selector("canvas", state="attached", timeout=60_000)
        page.wait_for_timeout(5000)
        shot = np.asarray(Image.open(io.BytesIO(page.screenshot(timeout=90_000))))
        assert not rerun_crashed(page)
        assert not [e for e in errors if "panic" in e.lower()]
        return shot[..., :3].astype(np.int16)
    finally:
        page.close()


def test_recording_replays_in_the_web_viewer(browser_context, recording):
    with WebViewer(recording, layout="iterations") as viewer:
        assert viewer.url.startswith("http://127.0.0.1:")
        assert _shot(browser_context, viewer).std() > 10
    assert viewer.proc.poll() is not None  # the server is gone


def test_replay_view_shows_that_view(browser_context, recording):
    """`--view` opens the confidence layout on that view's tab: the pictures differ from another view's (view 0
    has an error map, view 1 says it has none). egui draws text into a canvas, so the titles themselves are
    checked on the blueprint the viewer loads (test_layouts_name_the_chosen_view_and_say_what_is_missing)."""
    shots = []
    for view in ("img/0.png", "img/1.png"):
        with WebViewer(recording, layout="confidence", view=view) as viewer:
            shots.append(_shot(browser_context, viewer))
    assert all(shot.std() > 10 for shot in shots)
    assert np.abs(shots[0] - shots[1]).mean() > 1


def test_a_run_recording_says_what_it_will_not_record(tmp_path):
    """A run thinned to view 1 (--set stream.view=1) embeds a layout of view 1, and its recording says that the
    other views' maps and the vanilla pipeline's confidence are not recorded, instead of empty panels."""
    from engine.run.pipeline import PipelineOptions
    from engine.scene import load_scene
    from workbench.rerun.options import StreamOptions
    from workbench.rerun.run_recording import open_run_recording

    scene = load_scene("sample_scenes/tiny")
    recording = open_run_recording(str(tmp_path / "run.rrd"), scene, PipelineOptions(), StreamOptions(view=1))
    recording.finish()
    first, second = (entity_name(v.index, v.name) for v in scene.views[:2])
    docs = notes(tmp_path / "run.rrd")
    assert "no PatchMatch iterations of this view" in docs[f"/missing/{first}/depth"]
    assert "fast and full pipelines" in docs[f"/missing/{second}/confidence"]
    assert f"/missing/{second}/depth" not in docs
    titles = blueprint_titles(tmp_path / "run.rrd")
    assert f"depth · {scene.views[1].name} (view 1)" in titles


def test_a_recording_from_before_per_view_timelines_still_replays(tmp_path):
    """Recordings made before this change (one global `iteration` timeline, no legend) get a layout on that
    timeline, an about panel saying so, and the legend from the notes recording."""
    import rerun as rr

    path = tmp_path / "old.rrd"
    recording = Recording(path)
    view = entity_name(0, "a.png")
    for step in range(3):
        recording.rec.set_time("iteration", sequence=step)
        recording.rec.log(f"maps/{view}/depth", rr.DepthImage(np.ones((4, 6), np.float16), meter=1.0))
    recording.finish()
    contents = recording_contents(path).contents
    assert contents.timelines == {"iteration"} and contents.timeline == "iteration"
    rbl, notes_rrd = layout_files(path, "iterations", tmp_path)
    assert "depth · a.png (view 0)" in blueprint_titles(rbl)
    docs = notes(notes_rrd)
    assert "Recorded before per-view timelines" in docs["/about"] and "Colour legends" in docs["/legend"]
