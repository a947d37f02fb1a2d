"""Legends and histograms of the viewer as small HTML blocks (viser's ``add_html``): a colour bar with its
range and unit, the "no data" colour on its own swatch, and histograms with the current threshold drawn.

Plain strings, no viser: the colours come from the same matplotlib colormaps as ``workbench/maps/images.py``.
"""

from __future__ import annotations

import dataclasses
import html

import numpy as np

NO_DATA = (128, 128, 128)  # the colour of "no data" in every map and cloud colouring (no colormap here has it)
THRESHOLD = "#e8341c"  # the threshold line on the histograms


@dataclasses.dataclass(frozen=True)
class Scale:
    """A continuous colour scale: ``cmap`` from ``vmin`` to ``vmax`` in ``unit``; values beyond saturate."""

    title: str
    vmin: float
    vmax: float
    cmap: str
    unit: str = ""
    no_data: str | None = None  # what the NO_DATA colour means here; None: it does not occur
    saturates: bool = False  # values above vmax take vmax's colour (the legend says "≥")
    digits: int = 2


def _hex(rgb) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb))


def _stops(cmap: str, count: int = 9) -> str:
    from matplotlib import colormaps  # lazy: matplotlib

    colors = colormaps[cmap](np.linspace(0.0, 1.0, count))[:, :3] * 255
    return ", ".join(f"{_hex(c)} {100 * i / (count - 1):.0f}%" for i, c in enumerate(colors))


def _swatch(color: str, text: str) -> str:
    return (f'<span style="display:inline-block;width:0.9em;height:0.9em;background:{color};'
            f'border:1px solid #888;vertical-align:middle;margin-right:0.3em"></span>{html.escape(text)}')


def _number(value: float, digits: int) -> str:
    return f"{value:.{digits}f}".rstrip("0").rstrip(".") if digits else f"{value:.0f}"


def scale_html(scale: Scale) -> str:
    """A colour bar with its title, both ends with the unit, and the no-data swatch when it occurs."""
    unit = f" {scale.unit}" if scale.unit else ""
    top = ("≥ " if scale.saturates else "") + _number(scale.vmax, scale.digits) + unit
    middle = _number((scale.vmin + scale.vmax) / 2, scale.digits) + unit
    parts = ['<div class="deepc-legend" style="font-size:0.8em;margin:0.2em 0">',
             f"<div><b>{html.escape(scale.title)}</b></div>",
             f'<div style="height:0.8em;border-radius:2px;background:linear-gradient(to right, {_stops(scale.cmap)})">'
             "</div>",
             '<div style="display:flex;justify-content:space-between">',
             f"<span>{html.escape(_number(scale.vmin, scale.digits) + unit)}</span>",
             f"<span>{html.escape(middle)}</span><span>{html.escape(top)}</span></div>"]
    if scale.no_data:
        parts.append(f"<div>{_swatch(_hex(NO_DATA), scale.no_data)}</div>")
    parts.append("</div>")
    return "".join(parts)


def categories_html(title: str, entries: list[tuple[tuple[int, int, int], str]]) -> str:
    """A legend of named colours (a categorical map such as the kept mask)."""
    items = "".join(f'<div>{_swatch(_hex(color), text)}</div>' for color, text in entries)
    return (f'<div class="deepc-legend" style="font-size:0.8em;margin:0.2em 0"><div><b>{html.escape(title)}</b></div>'
            f"{items}</div>")


def note_html(text: str) -> str:
    return f'<div class="deepc-legend" style="font-size:0.8em;margin:0.2em 0">{html.escape(text)}</div>'


def histogram_html(title: str, counts: np.ndarray, edges: np.ndarray, threshold: float | None, unit: str = "",
                   threshold_name: str = "threshold", below: str = "removed", shown: str | None = None,
                   axis: tuple[str, str] | None = None) -> str:
    """An SVG histogram (bar heights ∝ √count, so the small bins near a threshold stay visible) with the threshold
    as a vertical line and the share of values below it (``shown`` names the threshold in the text, else its
    value; ``axis`` labels both ends, else the outer bin edges)."""
    width, height = 280, 70
    counts = np.asarray(counts, np.float64)
    lo, hi = float(edges[0]), float(edges[-1])
    span = max(hi - lo, 1e-12)
    heights = np.sqrt(counts)
    peak = max(float(heights.max()) if len(heights) else 0.0, 1.0)
    bars = []
    for c, a, b in zip(heights, edges[:-1], edges[1:], strict=True):
        x = (float(a) - lo) / span * width
        w = max((float(b) - float(a)) / span * width - 1, 1)
        h = c / peak * height
        bars.append(f'<rect x="{x:.1f}" y="{height - h:.1f}" width="{w:.1f}" height="{h:.1f}" fill="#5b7bd5"/>')
    text = ""
    if threshold is not None:
        x = min(max((threshold - lo) / span, 0.0), 1.0) * width
        bars.append(f'<line x1="{x:.1f}" y1="0" x2="{x:.1f}" y2="{height}" stroke="{THRESHOLD}" stroke-width="2"/>')
        total = counts.sum()
        centres = (np.asarray(edges[:-1]) + np.asarray(edges[1:])) / 2
        share = 100 * counts[centres < threshold].sum() / total if total else 0.0
        text = (f'<div><span style="color:{THRESHOLD}">▍</span>{html.escape(threshold_name)} '
                f"{html.escape(shown or _number(threshold, 2) + unit)}: {share:.1f} % {html.escape(below)}</div>")
    unit_text = f" {unit}" if unit else ""
    left, right = axis or (_number(lo, 2) + unit_text, _number(hi, 2) + unit_text)
    return (f'<div class="deepc-histogram" style="font-size:0.8em;margin:0.2em 0"><div><b>{html.escape(title)}</b>'
            f"</div>"
            f'<svg viewBox="0 0 {width} {height}" width="100%" height="{height}" preserveAspectRatio="none">'
            f'{"".join(bars)}</svg>'
            f'<div style="display:flex;justify-content:space-between"><span>{html.escape(left)}</span>'
            f"<span>√count</span><span>{html.escape(right)}</span></div>{text}</div>")


def _delta(value: float, reference: float | None, digits: int = 1) -> str:
    if reference is None:
        return "–"
    change = value - reference
    color = "#2a8a2a" if change > 0 else "#c0392b" if change < 0 else "inherit"
    return f'<span style="color:{color}">{change:+,.{digits}f}</span>'


def metrics_html(scores: dict | None, run: dict[float, dict] | None, previous: dict | None, points: int,
                 run_points: int | None) -> str:
    """The exact result's scores at every tolerance with their changes against the run's own metrics.json
    and against the previous setting; the point count against the run's."""
    style = 'style="padding:0 0.35em;text-align:right"'
    rows = ['<div class="deepc-metrics" style="font-size:0.8em"><table style="border-collapse:collapse">',
            f"<tr><th {style}></th><th {style}>value</th><th {style}>Δ run</th><th {style}>Δ previous</th></tr>"]
    prev_points = previous.get("_points") if previous else None
    rows.append(f"<tr><td {style}>points</td><td {style}>{points:,}</td>"
                f"<td {style}>{_delta(points, run_points, 0) if run_points else '–'}</td>"
                f"<td {style}>{_delta(points, prev_points, 0)}</td></tr>")
    if scores and "by_tolerance" in scores:
        previous_by = (previous or {}).get("by_tolerance") or {}
        for tol, s in sorted(scores["by_tolerance"].items()):
            ref = (run or {}).get(tol)
            old = previous_by.get(tol)
            rows.append(f"<tr><td {style}>F1 @ {100 * tol:g} cm</td><td {style}>{s['f1']:.1f}</td>"
                        f"<td {style}>{_delta(s['f1'], ref['f1'] if ref else None)}</td>"
                        f"<td {style}>{_delta(s['f1'], old['f1'] if old else None)}</td></tr>")
        rows.append(f'<tr><td colspan="4" {style}>accuracy / completeness @ 2 cm: {scores["accuracy"]:.1f} / '
                    f'{scores["completeness"]:.1f} %</td></tr>')
    elif scores is None:
        rows.append(f'<tr><td colspan="4" {style}>no GT points: no scores</td></tr>')
    rows.append("</table>")
    rows.append("<div>Δ run: against the run's metrics.json (its own settings); Δ previous: against the setting "
                "before this one; F1 in %</div></div>")
    return "".join(rows)
