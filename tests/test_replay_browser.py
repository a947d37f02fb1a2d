"""A recorded .rrd replays in the rerun web viewer (real chromium) with every layout."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from engine.errors import DeepCError
from workbench.browser import rerun_crashed
from workbench.recording import Recording
from workbench.replay import WebViewer, layout_file, recording_views
from workbench.stream import entity_name

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from test_stream import _events, _stream

    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    rec = Recording(path)
    stream = _stream(rec.rec)
    for event in _events(2, 4):
        stream.on_iteration(event)
    rec.finish()
    return path


def test_recording_views_and_layouts(recording, tmp_path):
    assert recording_views(recording) == [entity_name(0, "img/0.png"), entity_name(1, "img/1.png")]
    for name in ("iterations", "pipelines", "confidence"):
        assert layout_file(recording, name, tmp_path).stat().st_size > 0
    with pytest.raises(DeepCError, match="unknown layout"):
        layout_file(recording, "nope", tmp_path)


def test_bad_recordings_are_refused(tmp_path):
    (tmp_path / "x.rrd").write_bytes(b"not a recording")
    with pytest.raises(DeepCError, match="x.rrd"):
        recording_views(tmp_path / "x.rrd")
    with pytest.raises(DeepCError, match="not found"):
        WebViewer(tmp_path / "missing.rrd")


def test_recording_replays_in_the_web_viewer(browser_context, recording):
    with WebViewer(recording, layout="iterations") as viewer:
        assert viewer.url.startswith("http://127.0.0.1:")
        page = browser_context.new_page()
        errors = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        try:
            page.goto(viewer.url + "&renderer=webgl")
            page.wait_for_selector("canvas", state="attached", timeout=60_000)
            page.wait_for_timeout(5000)
            shot = np.asarray(Image.open(io.BytesIO(page.screenshot(timeout=90_000))))
            assert not rerun_crashed(page)
            assert shot[..., :3].std() > 10
            assert not [e for e in errors if "panic" in e.lower()]
        finally:
            page.close()
    assert viewer.proc.poll() is not None  # the server is gone
