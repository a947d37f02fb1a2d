"""A probed pixel's trace drawn for people: plots, the candidate table and a summary.

A trace is the dict ``engine.run.probe.probe_run`` returns (and ``deepc run --probe`` writes as
``OUT/probes/<view>/<x>_<y>.json``): per PatchMatch iteration in run order the pixel's hypothesis before and
after, every candidate it evaluated with its per-source-view costs and selected views, the winner and what
decided it; and the final estimate with the counter verdicts, confidence, GT depth, label and error. The
viewer's inspector (``workbench/viewer/inspector.py``) and its rerun stream (``workbench/rerun/probe.py``)
both draw from here. Nothing here imports viser.

The cost is ACMM's view-weighted 1 − NCC (Xu & Tao 2019; 0 = perfect, 2 = no match); selected views are the
source views the Monte-Carlo view selection kept for the pixel (Kuhn et al. 2020, §3.1).
"""

from __future__ import annotations

import html
import math
import textwrap
from typing import Any

import numpy as np

from engine.core.words import plural

SELECTED, OTHER = "#2a9d4b", "#b5b5b5"  # bar colours of selected / not selected source views
LABELS = {1: "inlier", 0: "outlier", -1: "unlabelled", "inlier": "inlier", "outlier": "outlier"}
# candidate colours by origin (the part before ':'), in the viewer's scene and in rerun
ORIGIN_COLOURS = {"current": (120, 120, 120), "upsampled": (150, 110, 60), "pattern": (60, 120, 230),
                  "perturbation": (230, 140, 30), "random": (200, 60, 200), "combination": (40, 180, 170),
                  "restorer": (150, 110, 60)}
WITHIN = 0.01  # the "within 1 %" band of the depth plot (relative to the GT depth)
# The inspector shows its figures at the width of an image in viser 1.1's default control panel (20 em of 16 px
# less the folder's padding: 281 CSS px in chromium): drawn for that width in CSS pixels, text is as large on
# screen as it is set here (1 pt = 100/72 CSS px), and PIXEL_RATIO image pixels per CSS pixel keep it sharp on
# high-density screens.
PANEL_PX = 280
PIXEL_RATIO = 2
FONT_PT = 8.0  # the smallest text of a figure: 11 CSS px
TITLE_CHARS = 40  # a title line that fits PANEL_PX at FONT_PT


def _number(value: Any) -> float:
    return float("nan") if value is None else float(value)


def iteration_label(step: dict) -> str:
    """``L1 p0 i3 red``: the level, pass, iteration and colour of one trace entry."""
    colour = step.get("colour")
    colour = {0: "red", 1: "black"}.get(colour, colour)
    return f"L{step['level']} p{step['pass']} i{step['iteration']}" + (f" {colour}" if colour is not None else "")


def trace_arrays(trace: dict) -> dict[str, np.ndarray]:
    """Per trace entry: ``cost`` and ``depth`` after the iteration, the ``level`` and ``pass`` (all (n,))."""
    steps = trace["iterations"]
    return {"cost": np.array([_number(s["after"]["cost"]) for s in steps], np.float64),
            "depth": np.array([_number(s["after"]["depth"]) for s in steps], np.float64),
            "level": np.array([s["level"] for s in steps], np.int64),
            "pass": np.array([s["pass"] for s in steps], np.int64)}


def _key(step: dict) -> tuple:
    return step["level"], step["pass"], step["iteration"]


def _pass_starts(arrays: dict[str, np.ndarray]) -> list[tuple[int, str]]:
    """(entry index, "L<level> p<pass>") where a new (level, pass) starts."""
    out = []
    for i, (level, pass_) in enumerate(zip(arrays["level"], arrays["pass"], strict=True)):
        if i == 0 or level != arrays["level"][i - 1] or pass_ != arrays["pass"][i - 1]:
            out.append((i, f"L{level} p{pass_}"))
    return out


def fitting_labels(starts: list[tuple[int, str]], px_per_entry: float, font_px: float) -> list[tuple[int, str]]:
    """The pass labels (``(entry, "L<level> p<pass>")`` of :func:`_pass_starts`) that fit side by side at
    ``px_per_entry`` CSS pixels per entry and ``font_px`` text: all of them when each has room before the next,
    else the levels' (``L2`` at the first pass shown of each level), those that fit; a label needs about 0.6 em a
    character and a gap."""
    def fit(labels: list[tuple[int, str]]) -> list[tuple[int, str]]:
        kept, free_from = [], -np.inf
        for start, name in labels:
            if start * px_per_entry >= free_from:
                kept.append((start, name))
                free_from = start * px_per_entry + 0.6 * font_px * len(name) + 4
        return kept

    every = fit(starts)
    if len(every) == len(starts):
        return every
    levels, seen = [], set()
    for start, name in starts:
        level = name.split()[0]
        if level not in seen:  # a level's first pass shown (a region re-run may start after its p0)
            seen.add(level)
            levels.append((start, level))
    return fit(levels)


def trace_figure(trace: dict, entry: int | None = None, title: str = "", size: tuple[int, int] = (PANEL_PX, 500),
                 compare: dict | None = None, pixel_ratio: int = PIXEL_RATIO) -> np.ndarray:
    """(H, W, 3) uint8 picture of :func:`trace_plot` at ``pixel_ratio`` image pixels per CSS pixel of ``size``."""
    fig = trace_plot(trace, entry, title, size, compare, pixel_ratio)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def trace_plot(trace: dict, entry: int | None = None, title: str = "", size: tuple[int, int] = (PANEL_PX, 500),
               compare: dict | None = None, pixel_ratio: int = PIXEL_RATIO) -> Any:
    """A matplotlib Figure of a trace: cost and depth against the iteration (level and pass boundaries
    marked, the GT depth and its ±1 % band when known), and the per-source-view costs of entry ``entry``'s
    winning candidate (default: the last), selected views in green.

    Args:
        trace: a probe trace (module docstring).
        entry: index into ``trace["iterations"]`` whose view costs the bottom plot shows.
        title: the figure's title (the pixel and view).
        size: (width, height) in CSS pixels, the size it is shown at (text is set for it: ``FONT_PT`` at least).
        compare: another trace of the same pixel (the run's, before a region re-run) drawn dashed in grey.
        pixel_ratio: image pixels per CSS pixel.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # lazy: matplotlib (no pyplot: thread-safe)
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator  # lazy: matplotlib

    width, height = size
    fig = Figure(figsize=(width / 100, height / 100), dpi=100 * pixel_ratio)
    small = FONT_PT
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, gridspec_kw={"height_ratios": [1, 1, 1.1]})
    steps = trace["iterations"]
    arrays = trace_arrays(trace)
    x = np.arange(len(steps))
    if compare is not None and compare.get("iterations"):
        # a region re-run starts at a later (level, pass): its entries sit where the run's same entries sit
        where = {_key(s): i for i, s in enumerate(compare["iterations"])}
        if all(_key(s) in where for s in steps):
            x = np.array([where[_key(s)] for s in steps])
    final = trace.get("final") or {}
    gt = final.get("gt_depth")
    for ax, key, label in ((axes[0], "cost", "cost (1 − NCC)"), (axes[1], "depth", "depth (m)")):
        if compare is not None and compare.get("iterations"):
            other = trace_arrays(compare)[key]
            ax.plot(np.arange(len(other)), other, "--", color="#999999", lw=1, label="before re-run")
        ax.plot(x, arrays[key], "-o", ms=2.5, lw=1.2, color="#1f5fa8", label="after each iteration")
        passes = trace_arrays(compare) if compare is not None and len(x) and x[0] > 0 else arrays
        starts = _pass_starts(passes)
        for start, _ in starts:
            ax.axvline(start - 0.5, color="#dddddd", lw=0.8)
        if key == "cost":
            # entries per CSS pixel of the axes (about 3/4 of the figure's width)
            px_per_entry = 0.75 * width / max(1, len(passes["level"]))
            for start, name in fitting_labels(starts, px_per_entry, small * 100 / 72):
                ax.text(start, 1.0, name, fontsize=small, color="#777777", transform=ax.get_xaxis_transform(),
                        va="bottom")
        if entry is not None and 0 <= entry < len(x):
            ax.axvline(x[entry], color="#e07b00", lw=1)
        ax.set_ylabel(label, fontsize=small)
        ax.tick_params(labelsize=small)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    if gt is not None and gt > 0:
        axes[1].axhline(gt, color="#2a9d4b", ls="--", lw=1, label="GT depth")
        axes[1].axhspan(gt * (1 - WITHIN), gt * (1 + WITHIN), color="#2a9d4b", alpha=0.12, label="±1 %")
    axes[1].legend(fontsize=small, loc="best")
    axes[1].set_xlabel("iteration (run order)", fontsize=small)
    index = len(steps) - 1 if entry is None else entry
    names = list(trace.get("source_views") or [])
    ax = axes[2]
    if steps and 0 <= index < len(steps):
        step = steps[index]
        winner = step["candidates"][step["winner"]] if step.get("candidates") else None
        if winner is not None:
            costs = np.array([_number(c) for c in winner.get("view_costs") or []], np.float64)
            selected = set(winner.get("selected_views") or [])
            labels = [_short(n) for n in names[:len(costs)]] or [str(i) for i in range(len(costs))]
            colours = [SELECTED if n in selected else OTHER for n in names[:len(costs)]]
            shown = np.nan_to_num(costs, nan=0.0)
            ax.bar(np.arange(len(costs)), shown, color=colours)
            for i, c in enumerate(costs):
                if not np.isfinite(c):
                    ax.text(i, 0.02, "n/e", ha="center", fontsize=small, color="#777777")
            ax.set_xticks(np.arange(len(costs)), labels, fontsize=small, rotation=40, ha="right")
            ax.set_ylim(0, 2)
            ax.set_title(f"winner's view costs · {iteration_label(step)}\n{winner['origin']} · green: selected",
                         fontsize=small)
    ax.set_ylabel("view cost", fontsize=small)
    ax.tick_params(labelsize=small)
    lines = textwrap.wrap(title, TITLE_CHARS, break_on_hyphens=False) if title else []
    if lines:
        fig.suptitle("\n".join(lines), fontsize=small + 1)
    # fixed margins (in CSS px, as the text is): tight_layout measured every tick label and took a third of the
    # figure's time
    top = (24 + 15 * len(lines)) / height  # the title's lines and the pass names above the first plot
    fig.subplots_adjust(left=52 / width, right=1 - 8 / width, top=1 - top, bottom=62 / height, hspace=0.95)
    return fig


def _short(name: str, keep: int = 12) -> str:
    """An image name without folder and extension, shortened to its last ``keep`` characters for labels."""
    name = str(name).rsplit("/", 1)[-1]
    name = name.rsplit(".", 1)[0] if "." in name[1:] else name
    return name if len(name) <= keep else "…" + name[-keep + 1:]


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "–"
    value = float(value)
    return "–" if not math.isfinite(value) else f"{value:.{digits}g}"


def candidate_table_html(trace: dict, entry: int) -> str:
    """HTML table of the candidates of trace entry ``entry``, as wide as the panel whatever the number of source
    views: origin, depth and cost in columns, under each candidate its per-view costs as chips that wrap (the
    selected views' chips green, views not evaluated '·'), the winner in bold."""
    steps = trace["iterations"]
    if not steps:
        return "<p><i>the trace has no iterations</i></p>"
    step = steps[max(0, min(entry, len(steps) - 1))]
    names = list(trace.get("source_views") or [])
    chip = "display:inline-block;margin:1px 2px 1px 0;padding:0 3px;border-radius:3px;white-space:nowrap"
    rows = []
    for k, cand in enumerate(step.get("candidates") or []):
        selected = set(cand.get("selected_views") or [])
        chips = []
        for j, cost in enumerate(cand.get("view_costs") or []):
            name = names[j] if j < len(names) else str(j)
            shade = "#bfe6c8" if name in selected else "#eeeeee"
            chips.append(f"<span title='{html.escape(str(name))}' style='{chip};background:{shade}'>"
                         f"{html.escape(_short(name, 8))} {'·' if cost is None else f'{float(cost):.2f}'}</span>")
        weight = "font-weight:bold;background:#fff3d6;" if k == step.get("winner") else ""
        rows.append(f"<tr style='{weight}border-top:1px solid #bbb'><td>{html.escape(str(cand['origin']))}</td>"
                    f"<td>{_fmt(cand['depth'])}</td><td>{_fmt(cand['cost'], 3)}</td></tr>"
                    f"<tr style='{weight}'><td colspan='3' style='white-space:normal'>{''.join(chips)}</td></tr>")
    decided = html.escape(str(step.get("decided_by") or ""))
    return ("<div style='font-size:11px;max-width:100%'>"
            f"<b>{html.escape(iteration_label(step))}</b> · winner in bold"
            + (f" · decided by <i>{decided}</i>" if decided else "")
            + " · under each candidate its cost in each source view, green: selected"
            "<table style='border-collapse:collapse;width:100%;table-layout:fixed' cellpadding='2'>"
            "<tr><th style='text-align:left'>origin</th><th style='text-align:left'>depth (m)</th>"
            f"<th style='text-align:left'>cost</th></tr>{''.join(rows)}</table></div>")


def candidate_table_markdown(trace: dict, entry: int) -> str:
    """The candidates of trace entry ``entry`` as a markdown table (rerun's text panels): origin, depth, cost,
    the per-view costs (selected views starred) and the winner in bold."""
    steps = trace["iterations"]
    if not steps:
        return "*the trace has no iterations*"
    step = steps[max(0, min(entry, len(steps) - 1))]
    names = list(trace.get("source_views") or [])
    lines = [f"**{iteration_label(step)}** · decided by *{step.get('decided_by') or '?'}* · * = selected view", "",
             "| origin | depth | cost | " + " | ".join(_short(n, 8) for n in names) + " |",
             "|---|---|---|" + "---|" * len(names)]
    for k, cand in enumerate(step.get("candidates") or []):
        selected = set(cand.get("selected_views") or [])
        costs = [("·" if c is None else f"{float(c):.2f}") + ("*" if j < len(names) and names[j] in selected else "")
                 for j, c in enumerate(cand.get("view_costs") or [])]
        cells = [str(cand["origin"]), _fmt(cand["depth"]), _fmt(cand["cost"], 3), *costs]
        if k == step.get("winner"):
            cells = [f"**{c}**" for c in cells]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary_markdown(trace: dict, view_label: str) -> str:
    """The pixel's final estimate in a few lines: depth against GT, error, label, confidence, cost and the
    counter's verdict per source view."""
    final = trace.get("final") or {}
    lines = [f"**pixel ({trace['x']}, {trace['y']}) of view {view_label}**"]
    depth, gt = final.get("depth"), final.get("gt_depth")
    text = f"depth {_fmt(depth)}"
    if gt is not None and gt > 0:
        text += f" · GT {_fmt(gt)}"
    error = final.get("error")
    if error is None and gt and depth and gt > 0:
        error = abs(depth - gt) / gt
    if error is not None:
        text += f" · error {100 * float(error):.2f} %" + (" ✔ within 1 %" if float(error) < WITHIN else " ✘")
    lines.append(text)
    extra = [f"cost {_fmt(final.get('cost'), 3)}"]
    if final.get("confidence") is not None:
        extra.append(f"confidence {float(final['confidence']):.2f}")
    label = final.get("label")
    if label is not None:
        extra.append("label " + LABELS.get(label, str(label)))
    lines.append(" · ".join(extra))
    verdicts = final.get("counter_verdicts") or {}
    if verdicts:
        details = final.get("counter_details") or {}
        groups: dict[str, list[str]] = {}
        for name, verdict in verdicts.items():
            why = details.get(name) or {}
            text = _short(name, 10)
            if verdict != "consistent" and why.get("reprojection_px") is not None:
                text += f" {why['reprojection_px']:.1f} px"
            groups.setdefault(verdict, []).append(text)
        agree = len(groups.get("consistent", []))
        lines.append(f"counter: {agree} of {plural(len(verdicts), 'source view')} consistent  \n"
                     + "; ".join(f"*{verdict}*: {', '.join(names)}" for verdict, names in groups.items()))
    steps = trace.get("iterations") or []
    if steps:
        last_change = max((i for i, s in enumerate(steps)
                           if _number(s["after"]["depth"]) != _number(s["before"]["depth"])), default=None)
        if last_change is not None:
            step = steps[last_change]
            winner = step["candidates"][step["winner"]]["origin"] if step.get("candidates") else "?"
            lines.append(f"last change at {iteration_label(step)} by *{winner}*")
    return "  \n".join(lines)
