"""The files of ``deepc compare --report DIR``: ``report.html``, ``compare.json`` and ``maps/<view>.<kind>.png``.

Each map PNG is the view's image, greyed and dimmed, with the pixels of one case coloured (:data:`COLOURS`): "A
right, B wrong", "B right, A wrong", "both wrong" (where GT exists) and "disagree" (where it does not), at the
pair's common size. The page (the style of ``deepc regress``'s report) has the runs, the overall and per-view
shares, both fused clouds' F1 against tolerance (and their maps' under our fusion, when asked), and the maps of
the views where the runs differ most. Every file is written under a temporary name and renamed.
"""

from __future__ import annotations

import html
import io
import math
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from engine.compare.comparison import Comparison, ViewComparison
from engine.compare.pixels import MAP_KINDS, MAP_TITLES, PixelCounts
from engine.compare.sources import SourceRun
from engine.io.atomic import atomic_write_bytes, atomic_write_text, write_json
from engine.io.images import resize_area, to_gray
from workbench.compare.colours import COLOURS
from workbench.regress.report.figures import eval_figure
from workbench.regress.report.page import CSS

#: rows of the shares tables: (key of PixelCounts.shares or a count, heading)
ROWS = (("gt", "GT pixels"), ("a_right", "A right %"), ("b_right", "B right %"),
        ("a_right_b_wrong", "A right, B wrong %"), ("b_right_a_wrong", "B right, A wrong %"),
        ("both_wrong", "both wrong %"), ("no_gt", "no GT, both have depth"), ("disagree", "disagree %"),
        ("only_a", "no GT, only A"), ("only_b", "no GT, only B"))


def _e(text: Any) -> str:
    return html.escape(str(text))


def map_file(name: str, kind: str) -> str:
    """The file name of a view's map (``/`` in image names becomes ``_``)."""
    return f"{name.replace('/', '_')}.{kind}.png"


def map_image(background: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    """(H, W, 3) uint8: ``background`` ((H, W, 3) float RGB in [0, 1]) grey at half brightness, ``mask`` coloured."""
    grey = (to_gray(background.astype(np.float32)) * 127).astype(np.uint8)
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    rgb[mask] = colour
    return rgb


def _png(rgb: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG", compress_level=3)
    return buffer.getvalue()


def write_maps(comparison: Comparison, folder: Path) -> None:
    """Write the four map PNGs of every compared view into ``folder``."""
    for view in comparison.views:
        image = comparison.scene.image(view.index)
        if image.shape[1::-1] != view.size:
            image = resize_area(image, view.size)
        for kind in MAP_KINDS:
            atomic_write_bytes(folder / map_file(view.name, kind), _png(map_image(image, view.maps[kind],
                                                                                 COLOURS[kind])))


def _cell(key: str, counts: PixelCounts) -> str:
    shares = counts.shares()
    if key in shares:
        return "–" if math.isnan(shares[key]) else f"{shares[key]:.2f}"
    return f"{getattr(counts, key):,}"


def _shares_table(views: list[ViewComparison], total: PixelCounts) -> str:
    head = "".join(f"<th>{_e(title)}</th>" for _, title in ROWS)
    rows = [f"<tr><th class=l>view</th>{head}</tr>"]
    for label, counts in [(v.name, v.counts) for v in views] + [("all views", total)]:
        rows.append(f"<tr><td class=l>{_e(label)}</td>" + "".join(f"<td>{_cell(k, counts)}</td>" for k, _ in ROWS)
                    + "</tr>")
    return "<table>" + "".join(rows) + "</table>"


def _fused_table(fused: dict[str, dict[str, list[float]] | None], title: str) -> str:
    a, b = fused.get("a"), fused.get("b")
    if a is None and b is None:
        return ""
    tolerances = (a or b)["tolerances"]
    head = ("<tr><th>tolerance</th><th>A accuracy %</th><th>A completeness %</th><th>A F1 %</th>"
            "<th>B accuracy %</th><th>B completeness %</th><th>B F1 %</th><th>F1 B − A</th></tr>")
    rows = [f"<caption class=l>{_e(title)}</caption>", head]
    for i, t in enumerate(tolerances):
        cells = []
        for block in (a, b):
            cells += ["–"] * 3 if block is None else [f"{block[k][i]:.2f}" for k in ("accuracy", "completeness", "f1")]
        change = "–" if a is None or b is None else f"{b['f1'][i] - a['f1'][i]:+.2f}"
        rows.append(f"<tr><td>{t:g}</td>" + "".join(f"<td>{c}</td>" for c in cells) + f"<td>{change}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def _maps_table(views: list[ViewComparison]) -> str:
    head = "".join(f"<th><span style='color:rgb{COLOURS[k]}'>■</span> {_e(MAP_TITLES[k])}</th>" for k in MAP_KINDS)
    rows = [f"<tr><th class=l>view</th>{head}</tr>"]
    for v in views:
        cells = "".join(f"<td><img width=320 alt='{_e(MAP_TITLES[k])} of {_e(v.name)}' "
                        f"src='maps/{_e(map_file(v.name, k))}'></td>" for k in MAP_KINDS)
        rows.append(f"<tr><td class=l>{_e(v.name)}<br>{v.difference:.1f} % differ</td>{cells}</tr>")
    return "<table class=thumbs>" + "".join(rows) + "</table>"


def _run_line(key: str, run: SourceRun) -> str:
    fused = "" if run.fused is None else f", fused cloud <code>{_e(run.fused.name)}</code>"
    return f"<li><b>{key}</b>: <code>{_e(run.path)}</code> ({_e(run.description)}{fused})</li>"


def render_report(comparison: Comparison, shown: int = 4) -> str:
    """The report as one HTML string; ``shown``: how many of the most different views get their maps shown."""
    c = comparison
    tol = f"{100 * c.tolerance:g} %"
    only = "".join(f"<p class=note>Views with a map in {k} only: {_e(', '.join(names))}</p>"
                   for k, names in (("A", c.only_a), ("B", c.only_b)) if names)
    curves = {"A": c.fused["a"], "B": c.fused["b"], "A, our fusion": c.ours_fused["a"],
              "B, our fusion": c.ours_fused["b"]}
    plot = eval_figure(curves) if any(curves.values()) else None
    body = [f"<h1>deepc compare: scene {_e(c.scene.name)}</h1>",
            "<ul>" + _run_line("A", c.a) + _run_line("B", c.b) + "</ul>",
            f"<p>{len(c.views)} views compared, each at the smaller of its two maps' sizes. Where GT depth exists a "
            f"run is right at a pixel when its depth is within {tol} of it (a missing depth is wrong); where it does "
            f"not, the runs disagree when both have a depth and they differ by more than {tol}.</p>", only,
            "<h2>Shares per view</h2>", _shares_table(c.views, c.total),
            "<h2>Fused clouds</h2>",
            _fused_table(c.fused, "each run's own fused cloud")
            + _fused_table(c.ours_fused, "each run's maps fused by our fusion (default options)")
            + "".join(f"<p class=muted>{_e(n)}</p>" for n in c.fused_notes),
            f"<div class=plots><img alt='F1 against tolerance' src='{plot}'></div>" if plot else "",
            f"<h2>Where they differ most ({min(shown, len(c.views))} of {len(c.views)} views)</h2>",
            _maps_table(c.most_different(shown))]
    return ("<!doctype html>\n<html lang=en><head><meta charset='utf-8'>"
            f"<title>deepc compare: {_e(c.scene.name)}</title><style>{CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def write_report(folder: str | Path, comparison: Comparison, shown: int = 4) -> Path:
    """Write ``compare.json``, the map PNGs and ``report.html`` (last) into ``folder``; returns the page's path."""
    folder = Path(folder)
    write_json(folder / "compare.json", comparison.to_dict())
    write_maps(comparison, folder / "maps")
    page = folder / "report.html"
    atomic_write_text(page, render_report(comparison, shown))
    return page
