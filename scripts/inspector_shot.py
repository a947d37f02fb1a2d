"""The README's inspector screenshot: a wrong pixel on an occlusion edge, explained, in headless Debian chromium.

    .venv/bin/python scripts/inspector_shot.py RUN_DIR [--view 0] [--pixel X,Y] [--out docs/inspector.png]

RUN_DIR is the output folder of ``deepc run`` on a scene with GT depth (with its pass history). Without
``--pixel`` the script picks an estimated pixel more than 5 % off GT within 2 px of a GT depth edge (a depth
jump of over 10 % between neighbours), nearest the image centre, and prints why it chose it. The panel keeps the
viewer's default width; the other folders are closed so that the Inspector fills it; the map plane shows the GT
error map in the 3-D view, the pixel marked (``--pixel 81,90`` of a ``--pipeline fast --max-image-size 192
--schedule acmm`` run for the README). The shot ends below the trace's figures; the PNG's colours are quantized to a
palette so that it stays small.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

from support.browser import chromium, dismiss_software_webgl_notice
from workbench.viewer.app import ViewerApp
from workbench.viewer.session import ViewerSession

OTHER_FOLDERS = ("Pipeline", "Fusion", "Display", "Metrics", "View")
COLOURS = 128  # palette entries of the PNG
WIDTH, HEIGHT = 1150, 2250  # tall enough for the whole Inspector folder at the default panel width


def occlusion_edge_pixel(session: ViewerSession, view: int) -> tuple[int, int]:
    """An estimated pixel > 5 % off GT within 2 px of a GT depth jump of > 10 %, nearest the image centre."""
    gt = session.scene.gt_depth(view)
    depth = session.data[view].depth
    safe = np.where(gt > 0, gt, np.nan)
    jump = np.zeros(gt.shape, bool)
    with np.errstate(invalid="ignore"):
        jump[:, 1:] |= np.abs(np.diff(safe, axis=1)) > 0.1 * safe[:, 1:]
        jump[1:, :] |= np.abs(np.diff(safe, axis=0)) > 0.1 * safe[1:, :]
        wrong = (depth > 0) & (gt > 0) & (np.abs(depth - gt) > 0.05 * gt)
    candidates = np.argwhere(wrong & ndimage.binary_dilation(jump, iterations=2))
    if not len(candidates):
        raise SystemExit("no wrong pixel on an occlusion edge in this view: give --pixel")
    h, w = gt.shape
    y, x = candidates[np.argmin(np.hypot(candidates[:, 0] - h / 2, candidates[:, 1] - w / 2))]
    print(f"pixel ({x}, {y}): depth {depth[y, x]:.3f}, GT {gt[y, x]:.3f} "
          f"({100 * abs(depth[y, x] - gt[y, x]) / gt[y, x]:.1f} % off), {len(candidates)} such pixels in the view")
    return int(x), int(y)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--view", type=int, default=0)
    parser.add_argument("--pixel", help="X,Y (default: a wrong pixel on an occlusion edge)")
    parser.add_argument("--out", type=Path, default=Path("docs/inspector.png"))
    args = parser.parse_args()
    app = ViewerApp(ViewerSession.open(args.run_dir), port=0)
    try:
        app.wait_idle(600)
        app.select_view(args.view)
        x, y = (int(v) for v in args.pixel.split(",")) if args.pixel else occlusion_edge_pixel(app.session, args.view)
        with chromium(WIDTH, HEIGHT, timeout_ms=120_000) as context:
            page = context.new_page()
            page.goto(f"http://127.0.0.1:{app.port}/")
            deadline = time.monotonic() + 60
            while not app.server.get_clients() and time.monotonic() < deadline:
                time.sleep(0.1)
            page.get_by_text("points").first.wait_for()
            dismiss_software_webgl_notice(page)
            for name in OTHER_FOLDERS:
                page.get_by_text(name, exact=True).first.click()
            page.get_by_text("Inspector", exact=True).click()
            app.inspector.plane_kind.value = "GT error"
            start = time.perf_counter()
            app.inspector.inspect(args.view, x, y, source="typed")
            app.inspector.wait_idle(600)
            page.get_by_text(f"pixel ({x}, {y}) of view").first.wait_for()
            print(f"inspector filled in {time.perf_counter() - start:.2f} s: {app.inspector.status.content}")
            page.wait_for_timeout(3000)
            dismiss_software_webgl_notice(page)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            # down to the iteration slider below the figures (the candidate table below it would be cut off)
            slider = page.get_by_text("Iteration", exact=True).last.bounding_box()
            bottom = min(HEIGHT, int(slider["y"] + slider["height"] + 8)) if slider else HEIGHT
            page.screenshot(path=str(args.out), timeout=120_000,
                            clip={"x": 0, "y": 0, "width": WIDTH, "height": bottom})
    finally:
        app.stop()
    Image.open(args.out).convert("RGB").quantize(COLOURS).save(args.out, optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
