"""The HTML report of ``deepc regress``: one self-contained file, every plot and thumbnail embedded.

Per scene and pipeline: the metrics against baseline and tolerance; F1, accuracy and completeness against
the evaluation tolerance (current and baseline); ROC curves of the confidence (and of the counter map, the
confidence a vanilla run already has); histograms of the relative depth error; thumbnails of the image,
depth, normal, counter, confidence and error maps; the options, the environment and the git revision.

ROC curves need inlier labels. Which pixels count as inliers is a :data:`LabelFunction`, so that the GT
label maps of SPEC.md §4.3 (``engine/confidence/labels.py``) take over when they exist; until then a
pixel is an inlier when its depth is within 1 % of GT.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from engine.io.atomic import atomic_write_text
from engine.metrics import roc_curve
from engine.scene import Scene

if TYPE_CHECKING:
    from workbench.regress import RunResult, Suite

# (scene, view index, depth (H, W)) -> (H, W) int8 labels: 1 inlier, 0 outlier, -1 unlabelled
LabelFunction = Callable[[Scene, int, np.ndarray], np.ndarray]
THUMBNAIL_WIDTH = 200
ERROR_MAP_MAX = 5.0  # percent: the error maps' colour scale
_ROC_POINTS = 400  # points per plotted ROC curve
_HIST_BINS = np.logspace(-4, 0, 49)  # relative depth error 0.01 % .. 100 %


# ---- labels and per-run analysis -----------------------------------------------------------------------

def relative_depth_labels(scene: Scene, index: int, depth: np.ndarray, threshold: float = 0.01) -> np.ndarray:
    """Inlier when |z - z*| / z* < ``threshold``; unlabelled without an estimate or without GT."""
    gt = scene.gt_depth(index)
    labels = np.full(depth.shape, -1, np.int8)
    if gt is None:
        return labels
    with np.errstate(invalid="ignore", divide="ignore"):
        both = (depth > 0) & np.isfinite(depth) & (gt > 0) & np.isfinite(gt)
        labels[both] = (np.abs(depth[both] - gt[both]) / gt[both] < threshold).astype(np.int8)
    return labels


def default_label_function() -> tuple[str, LabelFunction]:
    """(description, function): SPEC.md §4.3 labels when engine.confidence.labels exists, else 1 % depth error."""
    try:
        from engine.confidence.labels import label_map
    except ImportError:
        return "inlier: depth within 1 % of GT", relative_depth_labels

    def reprojection_labels(scene: Scene, index: int, depth: np.ndarray) -> np.ndarray:
        view = scene.views[index]
        gt = scene.gt_depth(index)
        if gt is None:
            return np.full(depth.shape, -1, np.int8)
        return label_map(depth, gt, view.camera, [scene.views[j].camera for j in view.source_views],
                         max_depth=view.depth_range[1])
    return "inlier: reprojection error < 2 px in a source view (SPEC §4.3)", reprojection_labels


@dataclasses.dataclass
class RunAnalysis:
    """What the report shows of one run folder besides its metrics.

    roc: score name -> (fpr, tpr, auc), fractions. errors: depth kind -> relative errors of all pixels
    with estimate and GT. thumbnails: (view name, {map kind: PNG data URI}) for the shown views.
    """

    label_name: str
    roc: dict[str, tuple[np.ndarray, np.ndarray, float]]
    errors: dict[str, np.ndarray]
    thumbnails: list[tuple[str, dict[str, str]]]


def _relative_error(depth: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) |z - z*| / z*, NaN where either is missing."""
    with np.errstate(invalid="ignore", divide="ignore"):
        both = (depth > 0) & np.isfinite(depth) & (gt > 0) & np.isfinite(gt)
        return np.where(both, np.abs(depth - gt) / np.where(both, gt, 1.0), np.nan)


def shown_views(count: int, wanted: int) -> list[int]:
    """Up to ``wanted`` view indices spread evenly over ``count`` views."""
    if wanted <= 0 or count == 0:
        return []
    return sorted(set(np.linspace(0, count - 1, min(wanted, count)).round().astype(int).tolist()))


def analyse_run(run_dir: str | Path, max_views: int = 4, labels: tuple[str, LabelFunction] | None = None
                ) -> RunAnalysis:
    """ROC curves, depth-error samples and map thumbnails of a ``deepc run`` output folder."""
    from workbench.session import ViewerSession
    from workbench.stream import colorize

    session = ViewerSession.open(run_dir)
    scene = session.scene
    label_name, label_fn = labels or default_label_function()
    scores: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    errors: dict[str, list[np.ndarray]] = {}
    shown = set(shown_views(len(scene.views), max_views))
    thumbnails = []
    for i, view in enumerate(scene.views):
        d = session.data[i]
        gt = scene.gt_depth(i)
        final = d.refined_depth if d.refined_depth is not None else d.depth
        if gt is not None:
            pm_labels = label_fn(scene, i, d.depth)
            if d.counter is not None:
                scores.setdefault("counter (PatchMatch depth)", []).append((d.counter, pm_labels))
            if d.confidence is not None:
                final_labels = pm_labels if final is d.depth else label_fn(scene, i, final)
                scores.setdefault("confidence", []).append((d.confidence, final_labels))
            errors.setdefault("PatchMatch", []).append(_relative_error(d.depth, gt))
            if d.refined_depth is not None:
                errors.setdefault("refined", []).append(_relative_error(d.refined_depth, gt))
        if i in shown:
            images = session.view_images(i)
            if d.refined_depth is not None:
                lo, hi = view.depth_range
                images["refined depth"] = colorize(d.refined_depth, lo, hi, "turbo", d.refined_depth <= 0)
            if gt is not None:
                error = _relative_error(final, gt) * 100
                rgb = colorize(error, 0.0, ERROR_MAP_MAX, "inferno")
                rgb[~np.isfinite(error)] = 128  # grey: no estimate or no GT (black is zero error)
                images["error"] = rgb
            thumbnails.append((view.name, {kind: png_data_uri(rgb, kind == "image") for kind, rgb in images.items()}))
    roc = {}
    for name, pairs in scores.items():
        roc[name] = roc_curve(np.concatenate([s.ravel() for s, _ in pairs]),
                              np.concatenate([y.ravel() for _, y in pairs]))
    pooled = {kind: np.concatenate([e.ravel() for e in maps]) for kind, maps in errors.items()}
    return RunAnalysis(label_name, roc, {k: v[np.isfinite(v)] for k, v in pooled.items()}, thumbnails)


# ---- images --------------------------------------------------------------------------------------------------

def png_data_uri(rgb: np.ndarray, smooth: bool = False, width: int = THUMBNAIL_WIDTH) -> str:
    """(H, W, 3) uint8 -> 'data:image/png;base64,...', shrunk to ``width`` (maps: nearest, never blended)."""
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(rgb))
    if image.width > width:
        size = (width, max(1, round(image.height * width / image.width)))
        image = image.resize(size, Image.Resampling.BOX if smooth else Image.Resampling.NEAREST)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _figure(width: float = 4.6, height: float = 3.3):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    return fig, fig.add_subplot()


def figure_data_uri(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def eval_figure(curves: dict[str, dict[str, Any]], baseline: dict[str, Any] | None = None) -> str | None:
    """F1 (solid), accuracy (dashed) and completeness (dotted) against tolerance, one colour per curve set
    (pipelines of a scene, or "current"); the baseline in grey."""
    curves = {name: block for name, block in curves.items() if block}
    if not curves and not baseline:
        return None
    fig, ax = _figure()
    sets = list(curves.items()) + ([("baseline", baseline)] if baseline else [])
    for n, (name, block) in enumerate(sets):
        color = "0.55" if name == "baseline" else f"C{n}"
        for key, style in (("f1", "-"), ("accuracy", "--"), ("completeness", ":")):
            ax.plot(block["tolerances"], block[key], style, color=color, marker="o", markersize=3,
                    label=f"{name} {'F1' if key == 'f1' else key}")
    ax.set_xscale("log")
    ax.set_xlabel("tolerance (model units)")
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.set_title("F1, accuracy, completeness vs tolerance")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    return figure_data_uri(fig)


def roc_figure(curves: dict[str, tuple[np.ndarray, np.ndarray, float]], label_name: str) -> str | None:
    if not curves:
        return None
    fig, ax = _figure()
    for n, (name, (fpr, tpr, auc)) in enumerate(curves.items()):
        step = max(1, len(fpr) // _ROC_POINTS)
        keep = np.unique(np.append(np.arange(0, len(fpr), step), len(fpr) - 1))
        ax.plot(fpr[keep], tpr[keep], color=f"C{n}", label=f"{name}: AUC {auc * 100:.2f}")
    ax.plot([0, 1], [0, 1], color="0.7", linestyle=":", linewidth=1)
    ax.set_xlabel("false positive rate (outliers kept)")
    ax.set_ylabel("true positive rate (inliers kept)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(f"ROC ({label_name})", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    return figure_data_uri(fig)


def error_histogram_figure(errors: dict[str, np.ndarray]) -> str | None:
    errors = {k: v for k, v in errors.items() if v.size}
    if not errors:
        return None
    fig, ax = _figure()
    for n, (name, values) in enumerate(errors.items()):
        counts, _ = np.histogram(np.clip(values, _HIST_BINS[0], _HIST_BINS[-1]), bins=_HIST_BINS)
        ax.stairs(100.0 * counts / values.size, _HIST_BINS * 100, color=f"C{n}",
                  label=f"{name}: median {np.median(values) * 100:.2f} %")
    for x in (1.0, 5.0):
        ax.axvline(x, color="0.5", linestyle=":", linewidth=1)
    ax.set_xscale("log")
    ax.set_xlabel("|z - z*| / z* (%), clipped to 0.01 .. 100")
    ax.set_ylabel("% of pixels with estimate and GT")
    ax.set_title("depth error")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    return figure_data_uri(fig)


# ---- HTML ----------------------------------------------------------------------------------------------------

_CSS = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 24px; color: #222; max-width: 1400px; }
h1 { font-size: 22px; } h2 { font-size: 18px; border-bottom: 1px solid #ccc; margin-top: 32px; }
h3 { font-size: 16px; margin-top: 24px; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #ddd; padding: 2px 8px; text-align: right; }
th { background: #f3f3f3; } td.l, th.l { text-align: left; }
.verdict { font-size: 18px; padding: 8px 12px; border-radius: 4px; display: inline-block; }
.pass { background: #dff3df; } .fail { background: #f9d6d5; }
tr.REGRESSED td, tr.MISSING td { background: #f9d6d5; } tr.improved td { background: #e3f0fb; }
tr.info td { color: #888; }
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


def _summary_table(results: list[RunResult]) -> str:
    rows = ["<tr><th class=l>run</th><th class=l>status</th><th>F1 @ headline tolerance</th>"
            "<th>depth within 1 %</th><th>confidence AUC</th><th>time (s)</th><th class=l>regressed</th></tr>"]
    for r in results:
        head = _headline(r.metrics.get("eval"))
        f1 = "-" if head is None else (f"{_num(_value(r.baseline, 'eval', 'f1', head[1]))} → "
                                       f"{_num(r.metrics['eval']['f1'][head[1]])} @ {head[0]:g}")
        status = "no baseline" if r.baseline is None else ("REGRESSED" if r.failures else "ok")
        css = "MISSING" if r.baseline is None else ("REGRESSED" if r.failures else "ok")
        rows.append(
            f"<tr class={css}><td class=l><a href='#{_anchor('run', r.spec.scene, r.spec.pipeline)}'>"
            f"{_e(r.spec.key)}</a></td><td class=l>{status}</td><td>{f1}</td>"
            f"<td>{_num(_value(r.baseline, 'depth', 'within_1pct'))} → "
            f"{_num(_value(r.metrics, 'depth', 'within_1pct'))}</td>"
            f"<td>{_num(_value(r.baseline, 'confidence_auc'))} → {_num(_value(r.metrics, 'confidence_auc'))}</td>"
            f"<td>{_num(_value(r.baseline, 'seconds', 'total'), 1)} → {_num(_value(r.metrics, 'seconds', 'total'), 1)}"
            f"</td><td class=l>{_e(', '.join(d.label for d in r.failures))}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def _delta_table(result: RunResult) -> str:
    from workbench.regress import _fmt, _fmt_allowed, _fmt_change

    rows = ["<tr><th class=l>metric</th><th>baseline</th><th>current</th><th>delta</th><th>allowed</th>"
            "<th class=l>status</th></tr>"]
    for d in result.deltas:
        status = "not compared" if d.status == "info" else d.status
        rows.append(f"<tr class={d.status}><td class=l title='{_e(d.spec.description)}'>{_e(d.label)}</td>"
                    f"<td>{_fmt(d, d.baseline)}</td><td>{_fmt(d, d.current)}</td><td>{_fmt_change(d)}</td>"
                    f"<td>{_fmt_allowed(d)}</td><td class=l>{status}</td></tr>")
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
    from workbench.regress import option_changes

    m = result.metrics
    parts = [f"<h3 id='{_anchor('run', result.spec.scene, result.spec.pipeline)}'>{_e(result.spec.key)}</h3>"]
    links = [_link(result.out_dir / "metrics.json", report_dir, "metrics.json"),
             _link(result.out_dir / "fused.ply", report_dir, "fused.ply")]
    if result.recording:
        links.append(_link(result.recording, report_dir, "recording.rrd") + " (deepc replay FILE.rrd)")
    seconds = m.get("seconds", {})
    parts.append(f"<p>{m.get('num_images')} views at {_e('×'.join(map(str, m.get('image_size', []))))}, pipeline "
                 f"{_e(m.get('pipeline'))}, {m.get('fused_points', 0):,} fused points; seconds: "
                 + ", ".join(f"{k} {v:.1f}" for k, v in seconds.items() if v)
                 + f" (1-min load average {result.load_average[0]:.1f} before, {result.load_average[1]:.1f} after)."
                 + f"<br>{' · '.join(links)}</p>")
    if result.baseline is None:
        parts.append("<p class=note>No baseline for this run: make one with <code>deepc regress "
                     "--update-baseline</code>.</p>")
    if result.baseline_reason:
        parts.append("<p class=note>Baseline remade on purpose: " + _e(result.baseline_reason) + "</p>")
    changes = option_changes(m, result.baseline)
    if changes:
        parts.append("<p class=note>Options differ from the baseline's: " + _e("; ".join(changes)) + "</p>")
    parts.append(_delta_table(result))
    parts.append(_plots(eval_figure({"current": m.get("eval")}, (result.baseline or {}).get("eval")),
                        roc_figure(analysis.roc, analysis.label_name), error_histogram_figure(analysis.errors),
                        alt=("F1 against tolerance", "ROC curves", "depth error histogram")))
    parts.append(_thumbnail_table(analysis))
    parts.append(f"<details><summary>options used (deepc run flags: <code>{_e(' '.join(result.spec.flags))}"
                 f"</code>)</summary><pre>{_e(json.dumps(m.get('options', {}), indent=2))}</pre></details>")
    return "\n".join(parts)


def _environment_table(env: dict[str, Any]) -> str:
    flat = {k: v for k, v in env.items() if k != "packages"}
    flat.update({f"package {k}": v for k, v in env.get("packages", {}).items()})
    return "<table>" + "".join(f"<tr><th class=l>{_e(k)}</th><td class=l>{_e(v)}</td></tr>"
                               for k, v in flat.items()) + "</table>"


def render_report(suite: Suite, results: list[RunResult], env: dict[str, Any], baseline_dir: Path,
                  updated: bool, report_dir: Path, analyses: list[RunAnalysis]) -> str:
    """The report as one HTML string."""
    failures = [d for r in results for d in r.failures]
    missing = [r.spec.key for r in results if r.baseline is None]
    if updated:
        verdict, css = "Baselines rewritten from this run (compared below with the previous baselines)", "pass"
    elif failures or missing:
        what = [d.explain() for d in failures] + [f"{k}: no baseline" for k in missing]
        verdict, css = "REGRESSED: " + "; ".join(what), "fail"
    else:
        verdict, css = "Nothing regressed", "pass"
    body = [f"<h1>deepc regress: suite {_e(suite.name)}</h1>",
            f"<p class='verdict {css}'>{_e(verdict)}</p>",
            f"<p>Suite <code>{_e(suite.path)}</code>, baselines <code>{_e(baseline_dir)}</code>, git revision "
            f"<code>{_e(env.get('git'))}</code>, {_e(env.get('date'))}. Runs are deterministic for a seed, so "
            "quality metrics repeat exactly on one machine; times depend on the machine's load (load averages "
            "are given per run). Tolerances are the allowed worsening; only a slower time regresses.</p>",
            "<h2>Summary</h2>", _summary_table(results)]
    by_scene: dict[str, list[tuple[RunResult, RunAnalysis]]] = {}
    for result, analysis in zip(results, analyses, strict=True):
        by_scene.setdefault(result.spec.scene, []).append((result, analysis))
    for scene, items in by_scene.items():
        body.append(f"<h2 id='{_anchor('scene', scene)}'>Scene {_e(scene)} "
                    f"<span class=muted>({_e(items[0][0].spec.scene_path)})</span></h2>")
        if len(items) > 1:  # pipelines side by side
            body.append(_plots(
                eval_figure({r.spec.pipeline: r.metrics.get("eval") for r, _ in items}),
                roc_figure({f"{r.spec.pipeline} {name}": curve for r, a in items for name, curve in a.roc.items()},
                           items[0][1].label_name),
                alt=("pipelines: F1 against tolerance", "pipelines: ROC curves")))
        body += [run_section(r, a, report_dir) for r, a in items]
    body += ["<h2>Environment</h2>", _environment_table(env)]
    return ("<!doctype html>\n<html lang=en><head><meta charset='utf-8'>"
            f"<title>deepc regress: {_e(suite.name)}</title><style>{_CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def write_report(path: str | Path, suite: Suite, results: list[RunResult], env: dict[str, Any],
                 baseline_dir: Path, updated: bool = False, labels: tuple[str, LabelFunction] | None = None) -> Path:
    """Analyse every run folder and write the report atomically; returns its path."""
    path = Path(path)
    labels = labels or default_label_function()
    analyses = [analyse_run(r.out_dir, suite.thumbnail_views, labels) for r in results]
    atomic_write_text(path, render_report(suite, results, env, baseline_dir, updated, path.parent, analyses))
    return path
