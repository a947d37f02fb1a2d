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
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from engine.core.errors import DeepCError
from layouts import LAYOUTS
from support.browser import rerun_crashed
from support.rerun_panels import explanation_problem, find_panel, layout_fractions, map_problem
from workbench.rerun.recording import Recording
from workbench.rerun.replay import (
    WebViewer,
    choose_view,
    layout_file,
    layout_files,
    recording_contents,
    recording_views,
)
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
    # a file replays paused; the latency rerun shows for a served file is not this replay's delay
    assert "opened paused" in docs["/about"] and "latency" in docs["/about"]
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
        errors: list[str] = []
        # both pipes read as they fill: a full one would block the viewer's writes, and so its stop
        for stream, into in ((proc.stdout, lines), (proc.stderr, errors)):
            threading.Thread(target=lambda s=stream, out=into: out.extend(line.strip() for line in s),
                             daemon=True).start()
        try:
            deadline = time.monotonic() + 120
            while len(lines) < 2 and time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.1)
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=60)
    assert len(lines) == 2, (lines, errors)
    moved = re.fullmatch(rf"rerun web viewer: port {port} is in use; serving on port (\d+) instead", lines[0])
    assert moved and int(moved.group(1)) > port, lines
    assert lines[1].startswith(f"rerun web viewer: http://127.0.0.1:{moved.group(1)}"), lines
    assert "\x1b[" not in "".join(lines)


def _panels_show(browser_context, viewer, recording, layout: str, view: str | None, checks: dict,
                 timeout_s: float = 120.0) -> None:
    """Screenshots of ``viewer`` until the panel of each title in ``checks`` shows what its check wants (a check
    takes the panel body's pixels and says what is wrong, or None), for at most ``timeout_s`` after the canvas
    appears; the panels are found where the layout the viewer was given puts them (support/rerun_panels.py).
    Fails with what each panel showed last (and the screenshot saved beside the recording)."""
    contents = recording_contents(recording).contents
    blueprint = LAYOUTS[layout](contents, choose_view(contents, view))
    shown = layout_fractions(blueprint)
    assert set(checks) <= set(shown), f"the layout has no panel {sorted(set(checks) - set(shown))} ({sorted(shown)})"
    page = browser_context.new_page()
    errors = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        page.goto(viewer.url + "&renderer=webgl")
        page.wait_for_selector("canvas", state="attached", timeout=60_000)
        deadline = time.monotonic() + timeout_s
        while True:
            png = page.screenshot(timeout=90_000)
            shot = np.asarray(Image.open(io.BytesIO(png)))[..., :3]
            assert not rerun_crashed(page)
            assert not [e for e in errors if "panic" in e.lower()]
            problems = {}
            for title, check in checks.items():
                try:
                    problem = check(find_panel(shot, blueprint, title).body().pixels(shot))
                except AssertionError as exc:  # the layout is not on the page (yet)
                    problem = str(exc)
                if problem:
                    problems[title] = problem
            if not problems:
                return
            if time.monotonic() > deadline:
                saved = Path(recording).with_name(f"{layout}_{view or 'first'}.png".replace("/", "_"))
                saved.write_bytes(png)
                pytest.fail(f"after {timeout_s:.0f} s the panels show: {problems} (screenshot: {saved})")
            page.wait_for_timeout(1000)
    finally:
        page.close()


def _shows_map(colormap: str):
    return lambda pixels: map_problem(pixels, colormap)


def test_recording_replays_in_the_web_viewer(browser_context, recording):
    """The iterations layout shows view 0's depth in turbo and its cost in magma, each in the panel of that name,
    and the panel of the counter (which the recording lacks) says why instead of staying empty."""
    with WebViewer(recording, layout="iterations") as viewer:
        assert viewer.url.startswith("http://127.0.0.1:")
        _panels_show(browser_context, viewer, recording, "iterations", None, {
            "000 · depth (m)": _shows_map("turbo"), "000 · cost": _shows_map("magma"),
            "000 · counter: not recorded": explanation_problem})
    assert viewer.proc.poll() is not None  # the server is gone


def test_replay_view_shows_that_view(browser_context, recording):
    """`--view` opens the confidence layout on that view's tab: view 0's error against GT is drawn in inferno in
    its panel; view 1, which has no GT, shows the explanation in that panel instead (the titles themselves are
    checked on the blueprint the viewer loads: test_layouts_name_the_chosen_view_and_say_what_is_missing)."""
    wanted = {"img/0.png": {"000 · error vs GT": _shows_map("inferno"),
                            "000 · GT labels: not recorded": explanation_problem},
              "img/1.png": {"001 · error vs GT: not recorded": explanation_problem,
                            "001 · confidence: not recorded": explanation_problem}}
    for view, checks in wanted.items():
        with WebViewer(recording, layout="confidence", view=view) as viewer:
            _panels_show(browser_context, viewer, recording, "confidence", view, checks)


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
    from layouts import Contents

    view = entity_name(0, "a.png")
    for layout in LAYOUTS.values():
        panel = layout(Contents([view], {f"/maps/{view}/depth"}, live=live), view).time_panel
        assert (panel.play_state, panel.loop_mode) == (("following", None) if live else ("paused", "off"))
