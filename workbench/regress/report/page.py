"""The HTML report of ``deepc regress``: one self-contained file, every plot and thumbnail embedded.

Per scene and pipeline: the metrics against baseline and tolerance (a change beyond it, either way, is
CHANGED with its direction; times are ratios to the baseline's after calibration, information only); F1,
accuracy and completeness against the evaluation tolerance (current and baseline); ROC curves of the
confidence (and of the counter map, the confidence a vanilla run already has); histograms of the relative
depth error; thumbnails of the image, depth, normal, counter, confidence and error maps; the options, the
environment and the git revision.
A run's metrics are read as :class:`engine.run.folder.RunMetrics`; its baseline's as stored.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path
from typing import Any

from engine.core.words import plural
from engine.io.atomic import atomic_write_text
from workbench.regress.calibration import Calibration
from workbench.regress.comparison import (
    describe_time,
    format_allowed,
    format_change,
    format_status,
    format_value,
    option_changes,
)
from workbench.regress.report.analysis import (
    ERROR_MAP_MAX,
    LabelFunction,
    RunAnalysis,
    analyse_run,
    default_label_function,
)
from workbench.regress.report.figures import error_histogram_figure, eval_figure, roc_figure
from workbench.regress.running import RunResult
from workbench.regress.suite import Suite

#: the style sheet of the HTML reports (this one and `deepc compare`'s)
CSS = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 24px; color: #222; max-width: 1400px; }
h1 { font-size: 22px; } h2 { font-size: 18px; border-bottom: 1px solid #ccc; margin-top: 32px; }
h3 { font-size: 16px; margin-top: 24px; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #ddd; padding: 2px 8px; text-align: right; }
th { background: #f3f3f3; } td.l, th.l { text-align: left; }
.verdict { font-size: 18px; padding: 8px 12px; border-radius: 4px; display: inline-block; }
.pass { background: #dff3df; } .fail { background: #f9d6d5; }
tr.CHANGED td, tr.MISSING td { background: #f9d6d5; } tr.better td { background: #fbe7c8; }
tr.info td { color: #888; } tr.slower td { color: #8a5a00; }
.plots img { margin: 4px 8px 4px 0; border: 1px solid #eee; }
.thumbs td { text-align: center; font-size: 11px; } .thumbs img { display: block; image-rendering: pixelated; }
pre { background: #f7f7f7; padding: 8px; font-size: 12px; overflow-x: auto; }
.note { color: #8a5a00; } .muted { color: #777; }
"""


def _e(text: Any) -> str:
    return html.escape(str(text))


def _anchor(*parts: str) -> str:
    return "-".join("".join(c if c.isalnum() else "_" for c in p) for p in parts)


def _headline(block: dict[str, Any] | None) -> tuple[float, int] | None:
    """(tolerance, index) of the headline tolerance: 0.02 when evaluated (ETH3D's), else the middle one."""
    if not block or not block.get("tolerances"):
        return None
    tols = block["tolerances"]
    for i, t in enumerate(tols):
        if abs(t - 0.02) < 1e-9:
            return t, i
    return tols[len(tols) // 2], len(tols) // 2


def _value(metrics: dict[str, Any] | None, *keys: Any) -> Any:
    value: Any = metrics
    for key in keys:
        try:
            value = value[key]
        except (KeyError, IndexError, TypeError):
            return None
    return value


def _num(value: Any, digits: int = 2, suffix: str = "") -> str:
    return "-" if not isinstance(value, (int, float)) else f"{value:.{digits}f}{suffix}"


def _time_ratio(result: RunResult) -> str:
    time = next((d for d in result.deltas if d.metric == "time"), None)
    return "" if time is None or time.ratio is None else f" ({describe_time(time)})"


def _summary_table(results: list[RunResult]) -> str:
    rows = ["<tr><th class=l>run</th><th class=l>status</th><th>F1 @ headline tolerance</th>"
            "<th>depth within 1 %</th><th>confidence AUC</th><th>time (s), information only</th>"
            "<th class=l>changed beyond tolerance</th></tr>"]
    for r in results:
        m = r.run
        head = _headline(m.eval)
        f1 = "-" if head is None else (f"{_num(_value(r.baseline, 'eval', 'f1', head[1]))} → "
                                       f"{_num(m.eval['f1'][head[1]])} @ {head[0]:g}")
        status = "no baseline" if r.baseline is None else ("CHANGED" if r.failures else "ok")
        css = "MISSING" if r.baseline is None else ("CHANGED" if r.failures else "ok")
        changed = ", ".join(f"{d.label} ({d.direction or 'missing'})" for d in r.failures)
        rows.append(
            f"<tr class={css}><td class=l><a href='#{_anchor('run', r.spec.scene, r.spec.pipeline)}'>"
            f"{_e(r.spec.key)}</a></td><td class=l>{status}</td><td>{f1}</td>"
            f"<td>{_num(_value(r.baseline, 'depth', 'within_1pct'))} → "
            f"{_num(_value(m.depth, 'within_1pct'))}</td>"
            f"<td>{_num(_value(r.baseline, 'confidence_auc'))} → {_num(m.confidence_auc)}</td>"
            f"<td>{_num(_value(r.baseline, 'seconds', 'total'), 1)} → {_num(m.seconds.get('total'), 1)}"
            f"{_e(_time_ratio(r))}</td><td class=l>{_e(changed)}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def _delta_table(result: RunResult) -> str:
    rows = ["<tr><th class=l>metric</th><th>baseline</th><th>current</th><th>delta</th><th>tolerance</th>"
            "<th class=l>status</th></tr>"]
    for d in result.deltas:
        status = "not compared" if d.status == "info" and not d.spec.timing else format_status(d)
        css = f"{d.status} {d.direction or ''} {'slower' if d.slower else ''}".strip()
        rows.append(f"<tr class='{css}'><td class=l title='{_e(d.spec.description)}'>{_e(d.label)}</td>"
                    f"<td>{format_value(d, d.baseline)}</td><td>{format_value(d, d.current)}</td>"
                    f"<td>{_e(format_change(d))}</td><td>{_e(format_allowed(d))}</td><td class=l>{_e(status)}</td>"
                    "</tr>")
    return "<table>" + "".join(rows) + "</table>"


def _thumbnail_table(analysis: RunAnalysis) -> str:
    if not analysis.thumbnails:
        return ""
    kinds: list[str] = []
    for _, images in analysis.thumbnails:
        kinds += [k for k in images if k not in kinds]
    captions = {"depth": "depth (turbo, view's depth range)", "normal": "normal (camera frame)",
                "counter": "counter (consistent views, 0..5)", "confidence": "confidence (0..1)",
                "error": f"|z - z*| / z* (0..{ERROR_MAP_MAX:g} %, grey: none)"}
    head = "".join(f"<th>{_e(captions.get(k, k))}</th>" for k in kinds)
    rows = [f"<tr><th class=l>view</th>{head}</tr>"]
    for name, images in analysis.thumbnails:
        cells = "".join(f"<td><img class=thumb alt='{_e(k)} of {_e(name)}' src='{images[k]}'></td>" if k in images
                        else "<td></td>" for k in kinds)
        rows.append(f"<tr><td class=l>{_e(name)}</td>{cells}</tr>")
    return "<table class=thumbs>" + "".join(rows) + "</table>"


def _plots(*uris: str | None, alt: tuple[str, ...]) -> str:
    return "<div class=plots>" + "".join(f"<img class=plot alt='{_e(a)}' src='{u}'>"
                                         for u, a in zip(uris, alt, strict=True) if u) + "</div>"


def _link(target: Path, report_dir: Path, text: str) -> str:
    return f"<a href='{_e(Path(os.path.relpath(target, report_dir)).as_posix())}'>{_e(text)}</a>"


def run_section(result: RunResult, analysis: RunAnalysis, report_dir: Path) -> str:
    """The report's section of one run: links, metrics against the baseline, plots, thumbnails, options."""
    m = result.run
    parts = [f"<h3 id='{_anchor('run', result.spec.scene, result.spec.pipeline)}'>{_e(result.spec.key)}</h3>"]
    links = [_link(result.out_dir / "metrics.json", report_dir, "metrics.json"),
             _link(result.out_dir / "fused.ply", report_dir, "fused.ply")]
    if result.recording:
        links.append(_link(result.recording, report_dir, "recording.rrd") + " (deepc replay FILE.rrd)")
    parts.append(f"<p>{plural(m.num_images, 'view')} at {_e('×'.join(map(str, m.image_size)))}, pipeline "
                 f"{_e(m.pipeline)}, {m.fused_points:,} fused points; seconds: "
                 + ", ".join(f"{k} {v:.1f}" for k, v in m.seconds.items() if v)
                 + f" (1-min load average {result.load_average[0]:.1f} before, {result.load_average[1]:.1f} after)."
                 + f"<br>{' · '.join(links)}</p>")
    if result.baseline is None:
        parts.append("<p class=note>No baseline for this run: make one with <code>deepc regress "
                     "--update-baseline</code>.</p>")
    if result.baseline is not None and result.baseline_calibration is None:
        parts.append("<p class=muted>The baseline has no calibration (made before calibrations were stored): "
                     "its time ratios are uncalibrated.</p>")
    if result.baseline_reason:
        parts.append("<p class=note>Baseline remade on purpose: " + _e(result.baseline_reason) + "</p>")
    changes = option_changes(result.metrics, result.baseline)
    if changes:
        parts.append("<p class=note>Options differ from the baseline's: " + _e("; ".join(changes)) + "</p>")
    parts.append(_delta_table(result))
    parts.append(_plots(eval_figure({"current": m.eval}, (result.baseline or {}).get("eval")),
                        roc_figure(analysis.roc, analysis.label_name), error_histogram_figure(analysis.errors),
                        alt=("F1 against tolerance", "ROC curves", "depth error histogram")))
    parts.append(_thumbnail_table(analysis))
    parts.append(f"<details><summary>options used (deepc run flags: <code>{_e(' '.join(result.spec.flags))}"
                 f"</code>)</summary><pre>{_e(json.dumps(m.options, indent=2))}</pre></details>")
    return "\n".join(parts)


def _environment_table(env: dict[str, Any]) -> str:
    flat = {k: v for k, v in env.items() if k != "packages"}
    flat.update({f"package {k}": v for k, v in env.get("packages", {}).items()})
    return "<table>" + "".join(f"<tr><th class=l>{_e(k)}</th><td class=l>{_e(v)}</td></tr>"
                               for k, v in flat.items()) + "</table>"


def render_report(suite: Suite, results: list[RunResult], env: dict[str, Any], baseline_dir: Path,
                  updated: bool, report_dir: Path, analyses: list[RunAnalysis],
                  calibration: Calibration | None = None) -> str:
    """The report as one HTML string."""
    failures = [d for r in results for d in r.failures]
    missing = [r.spec.key for r in results if r.baseline is None]
    if updated:
        verdict, css = "Baselines rewritten from this run (compared below with the previous baselines)", "pass"
    elif failures or missing:
        what = [d.explain() for d in failures] + [f"{k}: no baseline" for k in missing]
        verdict, css = "CHANGED: " + "; ".join(what), "fail"
    else:
        verdict, css = "Nothing changed", "pass"
    timing = (f"This invocation's calibration: {calibration.describe()} (median of the repeats before, between "
              "and after the runs). " if calibration else "")
    body = [f"<h1>deepc regress: suite {_e(suite.name)}</h1>",
            f"<p class='verdict {css}'>{_e(verdict)}</p>",
            f"<p>Suite <code>{_e(suite.path)}</code>, baselines <code>{_e(baseline_dir)}</code>, git revision "
            f"<code>{_e(env.get('git'))}</code>, {_e(env.get('date'))}. Runs are deterministic for a seed, so "
            "quality metrics repeat exactly on one machine. A quality metric that moves beyond its tolerance in "
            "either direction is CHANGED and fails the check (better or worse is shown) until the baselines are "
            "remade with <code>deepc regress --update-baseline --reason TEXT</code>. Times depend on the machine "
            "and its load (load averages are given per run): they are information only, each the ratio to the "
            "baseline's after normalising both by a calibration workload timed in the same invocation "
            "(uncalibrated where the baseline has no calibration). Speed regressions are caught by "
            f"<code>benchmarks/performance/</code>, not here. {_e(timing)}</p>",
            "<h2>Summary</h2>", _summary_table(results)]
    by_scene: dict[str, list[tuple[RunResult, RunAnalysis]]] = {}
    for result, analysis in zip(results, analyses, strict=True):
        by_scene.setdefault(result.spec.scene, []).append((result, analysis))
    for scene, items in by_scene.items():
        body.append(f"<h2 id='{_anchor('scene', scene)}'>Scene {_e(scene)} "
                    f"<span class=muted>({_e(items[0][0].spec.scene_path)})</span></h2>")
        if len(items) > 1:  # pipelines side by side
            body.append(_plots(
                eval_figure({r.spec.pipeline: r.run.eval for r, _ in items}),
                roc_figure({f"{r.spec.pipeline} {name}": curve for r, a in items for name, curve in a.roc.items()},
                           items[0][1].label_name),
                alt=("pipelines: F1 against tolerance", "pipelines: ROC curves")))
        body += [run_section(r, a, report_dir) for r, a in items]
    body += ["<h2>Environment</h2>", _environment_table(env)]
    return ("<!doctype html>\n<html lang=en><head><meta charset='utf-8'>"
            f"<title>deepc regress: {_e(suite.name)}</title><style>{CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def write_report(path: str | Path, suite: Suite, results: list[RunResult], env: dict[str, Any],
                 baseline_dir: Path, updated: bool = False, labels: tuple[str, LabelFunction] | None = None,
                 calibration: Calibration | None = None) -> Path:
    """Analyse every run folder and write the report atomically; returns its path."""
    path = Path(path)
    labels = labels or default_label_function()
    analyses = [analyse_run(r.out_dir, suite.thumbnail_views, labels) for r in results]
    atomic_write_text(path, render_report(suite, results, env, baseline_dir, updated, path.parent, analyses,
                                          calibration))
    return path
