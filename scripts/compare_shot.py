"""The README's comparison screenshot: ``deepc view RUN_A --compare RUN_B`` in headless Debian chromium.

    .venv/bin/python scripts/compare_shot.py RUN_A RUN_B [--view NAME] [--out docs/compare.png] [--max-points N]

RUN_A and RUN_B are any two runs ``deepc compare`` reads (for the README: our fountain_p11 768 run and the OpenMVS
peer's densify folder of the same scene). The panel names each run by the path given, so give neutral relative ones
(the README's: links ``runs/ours`` and ``runs/openmvs`` in a temporary folder, the script run from there). The panel
keeps its default width; the view shown is ``--view`` or the one where the runs differ most. Prints how long the
comparison took to open and to appear in the browser, then writes a PNG of the page, colours quantized to a palette
so that it stays small.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from PIL import Image

from support.browser import chromium, dismiss_software_webgl_notice
from workbench.viewer.compare import CompareApp, open_comparison

WIDTH, HEIGHT = 1280, 800
COLOURS = 128  # palette entries of the PNG


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_a", type=Path)
    parser.add_argument("run_b", type=Path)
    parser.add_argument("--view", default=None, help="the view whose maps the panel shows (default: most different)")
    parser.add_argument("--out", type=Path, default=Path("docs/compare.png"))
    parser.add_argument("--max-points", type=int, default=100_000, help="points per run (software WebGL is slow)")
    args = parser.parse_args()
    start = time.perf_counter()
    comparison = open_comparison(args.run_a, args.run_b)
    opened = time.perf_counter() - start
    app = CompareApp(comparison, port=0, max_points=args.max_points)
    built = time.perf_counter() - start
    try:
        view = next((v for v in comparison.views if v.name == args.view), None) or comparison.most_different(1)[0]
        app.select_view(view.index)
        with chromium(WIDTH, HEIGHT, timeout_ms=120_000) as context:
            page = context.new_page()
            page.goto(f"http://127.0.0.1:{app.port}/")
            deadline = time.monotonic() + 60
            while not app.server.get_clients() and time.monotonic() < deadline:
                time.sleep(0.1)
            page.locator(".deepc-compare-metrics").wait_for()
            shown = time.perf_counter() - start
            print(f"comparison {opened:.1f} s, viewer built {built:.1f} s, table in the browser {shown:.1f} s "
                  f"(view {view.name}, {view.difference:.1f} % of its pixels differ)")
            page.wait_for_timeout(3000)
            dismiss_software_webgl_notice(page)
            page.wait_for_timeout(1000)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(args.out), timeout=120_000)
    finally:
        app.stop()
    Image.open(args.out).convert("RGB").quantize(COLOURS).save(args.out, optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
