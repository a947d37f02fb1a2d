"""A recorded .rrd replays in the rerun web viewer (real chromium) with every layout, built per view."""

from __future__ import annotations

import io
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

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
    """--view by image name or index; every map panel is titled with the view first; a map the recording lacks
    (view 1 has no GT, nothing has a counter) is a text panel saying why, not an empty panel."""
    contents = recording_contents(recording).contents
    assert {"view_iteration", "pass", "iteration"} <= contents.timelines
    for view in ("img/1.png", "1"):
        rbl, notes_rrd = layout_files(recording, "iterations", tmp_path, view=view)
        titles = blueprint_titles(rbl)
        assert "001 · depth (m)" in titles and "001 · cost" in titles
        assert "001 · error vs GT: not recorded" in titles
        assert not [t for t in titles if t.startswith("000")]
    docs = notes(notes_rrd)
    assert "no GT depth" in docs[f"/missing/{entity_name(1, 'img/1.png')}/error"]
    assert f"/missing/{entity_name(0, 'img/0.png')}/error" not in docs  # view 0 has its error map
    assert "img/1.png (view 1)" in docs["/about"] and "view_iteration" in docs["/about"]
    # the confidence layout: a tab per view (not only the first 4), each with confidence, labels and error
    titles = blueprint_titles(layout_files(recording, "confidence", tmp_path, view="img/0.png")[0])
    for view, short in (("img/0.png (view 0)", "000"), ("img/1.png (view 1)", "001")):
        assert view in titles  # the tab
        assert f"{short} · confidence: not recorded" in titles and f"{short} · GT labels: not recorded" in titles
    assert "000 · error vs GT" in titles


def test_bad_recordings_are_refused(tmp_path):
    (tmp_path / "x.rrd").write_bytes(b"not a recording")
    with pytest.raises(DeepCError, match="x.rrd"):
        recording_views(tmp_path / "x.rrd")
    with pytest.raises(DeepCError, match="not found"):
        WebViewer(tmp_path / "missing.rrd")


def test_replay_on_a_port_in_use_serves_on_the_next_one_and_says_so(recording):
    """As `deepc view` and `deepc run` do: a busy port is not an error, the next free one is used and named."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "replay", str(recording), "--web",
                                 "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(line.strip() for line in proc.stdout), daemon=True)
        reader.start()
        try:
            deadline = time.monotonic() + 120
            while len(lines) < 2 and time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.1)
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=30)
    assert len(lines) == 2, (lines, proc.stderr.read())
    moved = re.fullmatch(rf"rerun web viewer: port {port} is in use; serving on port (\d+) instead", lines[0])
    assert moved and int(moved.group(1)) > port, lines
    assert lines[1].startswith(f"rerun web viewer: http://127.0.0.1:{moved.group(1)}"), lines
    assert "\x1b[" not in "".join(lines)


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
    assert "001 · depth (m)" in titles


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
    assert "000 · depth (m)" in blueprint_titles(rbl)
    docs = notes(notes_rrd)
    assert "Recorded before per-view timelines" in docs["/about"] and "Colour legends" in docs["/legend"]


@pytest.mark.parametrize("live", [False, True])
def test_a_file_opens_paused_without_looping_and_a_live_run_is_followed(live):
    """Replaying a file must not auto-play and loop it; a run streaming now is followed as it goes."""
    from layouts import LAYOUTS, Contents

    view = entity_name(0, "a.png")
    for layout in LAYOUTS.values():
        panel = layout(Contents([view], {f"/maps/{view}/depth"}, live=live), view).time_panel
        assert (panel.play_state, panel.loop_mode) == (("following", None) if live else ("paused", "off"))
