"""Screenshots of both viewers for the README, made in headless Debian chromium.

    .venv/bin/python scripts/screenshots.py RUN_DIR [--out docs]

RUN_DIR is the output folder of ``deepc run ... --record`` (it needs recording.rrd for the rerun
shot). Writes ``viewer.png`` (the viser viewer) and ``rerun.png`` (the recording replayed in the
rerun web viewer with the PatchMatch-iterations layout of the first view, at its last iteration).
"""

from __future__ import annotations

import argparse
import io
import time
from pathlib import Path

import numpy as np
from PIL import Image

from support.browser import chromium, dismiss_software_webgl_notice, rerun_crashed
from support.rerun_panels import following, panels_match
from workbench.rerun.replay import WebViewer
from workbench.viewer.app import ViewerApp
from workbench.viewer.session import ViewerSession

COLOURS = 192  # palette entries of the rerun PNG


def viewer_shot(run_dir: Path, out: Path) -> None:
    app = ViewerApp(ViewerSession.open(run_dir), port=0)
    try:
        app.wait_idle(120)
        with chromium(1280, 800) as context:
            page = context.new_page()
            page.goto(f"http://127.0.0.1:{app.port}/")
            deadline = time.monotonic() + 60
            while not app.server.get_clients() and time.monotonic() < deadline:
                time.sleep(0.1)
            page.get_by_text("points").first.wait_for()
            page.wait_for_timeout(1500)
            dismiss_software_webgl_notice(page)
            page.wait_for_timeout(3000)
            page.screenshot(path=str(out), timeout=90_000)
    finally:
        app.stop()


def rerun_shot(recording: Path, out: Path, settle_s: float = 20.0, timeout_s: float = 300.0) -> None:
    """The recording in the rerun web viewer with the iterations layout of its first view, its time panel following
    the newest data (``deepc replay`` opens paused at the start), shot once the page has not changed for
    ``settle_s`` (at most ``timeout_s``); the PNG's colours quantized to a palette."""
    with following("iterations"):
        viewer = WebViewer(recording, layout="iterations")
    with viewer, chromium(1280, 800, timeout_ms=90_000) as context:
        page = context.new_page()
        page.goto(viewer.url + "&renderer=webgl")
        page.wait_for_selector("canvas", state="attached")
        last, since, deadline = None, time.monotonic(), time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            shot = np.asarray(Image.open(io.BytesIO(page.screenshot(timeout=90_000))).convert("RGB"))
            if not panels_match(shot, last):
                last, since = shot, time.monotonic()
            elif time.monotonic() - since >= settle_s:
                break
            page.wait_for_timeout(2000)
        if rerun_crashed(page):
            raise RuntimeError("the rerun web viewer crashed")
        page.screenshot(path=str(out), timeout=90_000)
    Image.open(out).convert("RGB").quantize(COLOURS).save(out, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    viewer_shot(args.run_dir, args.out / "viewer.png")
    print(f"wrote {args.out / 'viewer.png'}")
    recording = args.run_dir / "recording.rrd"
    if recording.is_file():
        rerun_shot(recording, args.out / "rerun.png")
        print(f"wrote {args.out / 'rerun.png'}")


if __name__ == "__main__":
    main()
