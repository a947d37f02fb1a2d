"""A run's metrics against its baseline: the compared metrics, their tolerances, the deltas and how they read.

Quality is compared both ways: a metric with a tolerance that moves beyond it, better or worse, is
*changed* and fails ``deepc regress`` until the baselines are remade on purpose (``--update-baseline
--reason``), so that a bug that inflates F1 is caught like one that lowers it. F1, accuracy and completeness
are compared at *every* tolerance of the evaluation, not only at the 2 cm / 5 cm headline ones: the runs are
deterministic for a seed, so each of them is exact and a change at a fine tolerance (precision) is real
even when the coarse ones hide it. Higher is better except for ``abs_rel``; that only names the direction.

Times are never compared: ``time`` (the wall-clock total of the run) and ``cpu_time`` (its CPU seconds over
all threads, ``seconds_cpu``, added to metrics.json by regress) are reported as a ratio to the baseline's,
normalised by the calibration workload of ``workbench/regress/calibration.py`` when both sides have one
("uncalibrated" otherwise), with status ``info``. Their tolerance only marks a ratio as notably slower.
Speed regressions are caught by ``benchmarks/performance/``, not by a wall clock on a shared machine.

Both sides of a comparison are metrics.json dicts: the current run's and the one stored in its baseline
file (``workbench/regress/baselines.py``), which has the same keys.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions

#: (row label, value) pairs a metric reads from a metrics.json dict; several for per-tolerance scores
MetricValues = Callable[[dict[str, Any]], list[tuple[str, float | None]]]


@dataclasses.dataclass(frozen=True)
class MetricSpec:
    """A compared metric: how to read it from metrics.json and which direction is better.

    ``timing``: a time, reported as a ratio to the baseline's and never compared; its tolerance (a fraction,
    0.5 = 50 % slower) only marks a notable slowdown. Otherwise the tolerance is in the metric's units (points).
    ``values(metrics)`` returns (row label, value) pairs; several for per-tolerance scores.
    """

    name: str
    description: str
    higher_is_better: bool
    timing: bool
    default_tolerance: float | None
    values: MetricValues


def _eval_values(key: str) -> MetricValues:
    def values(metrics: dict[str, Any]) -> list[tuple[str, float | None]]:
        block = metrics.get("eval") or {}
        return [(f"{key}@{t:g}", v) for t, v in zip(block.get("tolerances", []), block.get(key, []), strict=True)]
    return values


def _nested_value(label: str, *keys: str) -> MetricValues:
    def values(metrics: dict[str, Any]) -> list[tuple[str, float | None]]:
        value: Any = metrics
        for key in keys:
            if not isinstance(value, dict) or key not in value:
                return []
            value = value[key]
        return [(label, value)]
    return values


METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("f1", "F1 of the fused cloud (%, per evaluation tolerance)", True, False, 0.5, _eval_values("f1")),
    MetricSpec("accuracy", "accuracy of the fused cloud (%)", True, False, 0.5, _eval_values("accuracy")),
    MetricSpec("completeness", "completeness of the fused cloud (%)", True, False, 0.5,
               _eval_values("completeness")),
    MetricSpec("within_1pct", "PatchMatch depth within 1 % of GT (%)", True, False, 0.5,
               _nested_value("within_1pct", "depth", "within_1pct")),
    MetricSpec("within_5pct", "PatchMatch depth within 5 % of GT (%)", True, False, 0.5,
               _nested_value("within_5pct", "depth", "within_5pct")),
    MetricSpec("valid_fraction", "GT pixels with a depth estimate (%)", True, False, 0.5,
               _nested_value("valid_fraction", "depth", "valid_fraction")),
    MetricSpec("abs_rel", "mean relative depth error", False, False, 0.001,
               _nested_value("abs_rel", "depth", "abs_rel")),
    MetricSpec("auc", "confidence ROC-AUC × 100", True, False, 0.5, _nested_value("auc", "confidence_auc")),
    MetricSpec("time", "wall-clock seconds of the run (reported, never compared)", False, True, 0.5,
               _nested_value("time", "seconds", "total")),
    MetricSpec("cpu_time", "CPU seconds of the run, all threads (reported, never compared)", False, True, 0.5,
               _nested_value("cpu_time", "seconds_cpu")),
)
METRIC_BY_NAME = {m.name: m for m in METRICS}
DEFAULT_TOLERANCES: dict[str, float | None] = {m.name: m.default_tolerance for m in METRICS}

OK, CHANGED, NEW, MISSING, INFO = "ok", "CHANGED", "new", "MISSING", "info"
BETTER, WORSE = "better", "worse"
FAILED = (CHANGED, MISSING)


@dataclasses.dataclass
class Delta:
    """One metric of one run against its baseline.

    ``direction``: ``better`` or ``worse`` when a quality metric changed beyond its tolerance. For times,
    ``ratio`` is current / baseline, multiplied by baseline / current calibration when ``calibrated``.
    """

    run: str
    metric: str
    label: str
    baseline: float | None
    current: float | None
    tolerance: float | None
    status: str
    direction: str | None = None
    ratio: float | None = None
    calibrated: bool = False

    @property
    def spec(self) -> MetricSpec:
        return METRIC_BY_NAME[self.metric]

    def change(self) -> float | None:
        """current - baseline (in the metric's units); for times the ratio - 1."""
        if self.spec.timing:
            return None if self.ratio is None else self.ratio - 1.0
        if self.baseline is None or self.current is None:
            return None
        return self.current - self.baseline

    @property
    def slower(self) -> bool:
        """A time whose ratio exceeds 1 + its tolerance (a note, never a failure)."""
        return self.spec.timing and None not in (self.ratio, self.tolerance) and self.ratio > 1 + self.tolerance

    def explain(self) -> str:
        """e.g. 'tiny/vanilla f1@0.02 47.60 -> 52.60 (+5.00, tolerance ±0.5): better by +5.00'."""
        if self.status == MISSING:
            return f"{self.run} {self.label}: missing (baseline {format_value(self, self.baseline)})"
        text = (f"{self.run} {self.label} {format_value(self, self.baseline)} -> {format_value(self, self.current)} "
                f"({format_change(self)}, tolerance {format_allowed(self)})")
        return f"{text}: {self.direction} by {format_change(self)}" if self.status == CHANGED else text


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def compare(run: str, current: dict[str, Any], baseline: dict[str, Any] | None,
            tolerances: dict[str, float | None], time_scales: dict[str, float] | None = None) -> list[Delta]:
    """Deltas of every metric the current run or its baseline reports.

    ``time_scales``: per timing metric, baseline calibration / current calibration
    (:func:`workbench.regress.calibration.time_scales`); None reports raw, uncalibrated time ratios.
    """
    deltas = []
    for spec in METRICS:
        tol = tolerances.get(spec.name)
        now = {label: _number(v) for label, v in spec.values(current)}
        before = {label: _number(v) for label, v in spec.values(baseline or {})}
        for label in list(now) + [k for k in before if k not in now]:
            b, c = before.get(label), now.get(label)
            delta = Delta(run, spec.name, label, b, c, tol, INFO)
            if spec.timing:
                if b is not None and c is not None and b > 0:
                    scale = (time_scales or {}).get(spec.name)
                    delta.ratio, delta.calibrated = c / b * (scale or 1.0), scale is not None
            elif tol is None:
                pass
            elif b is None:
                delta.status = NEW if c is not None else INFO
            elif c is None:
                delta.status = MISSING
            else:
                change = c - b
                # the small slack absorbs float noise in values that only went through JSON
                if abs(change) > tol + 1e-9:
                    delta.status = CHANGED
                    delta.direction = BETTER if (change > 0) == spec.higher_is_better else WORSE
                else:
                    delta.status = OK
            deltas.append(delta)
    return deltas


def format_value(delta: Delta, value: float | None) -> str:
    """A baseline or current value of ``delta``'s metric as the table and the report show it."""
    if value is None:
        return "-"
    if delta.spec.timing:
        return f"{value:.1f} s"
    if delta.metric == "abs_rel":
        return f"{value:.4f}"
    return f"{value:.2f}"


def format_change(delta: Delta) -> str:
    """The change of ``delta``, signed; for times the ratio ('1.05× calibrated', '6.70× uncalibrated')."""
    if delta.spec.timing:
        if delta.ratio is None:
            return "-"
        return f"{delta.ratio:.2f}× {'calibrated' if delta.calibrated else 'uncalibrated'}"
    change = delta.change()
    if change is None:
        return "-"
    return f"{change:+.4f}" if delta.metric == "abs_rel" else f"{change:+.2f}"


def format_allowed(delta: Delta) -> str:
    """The tolerance of ``delta``: ±points for quality; for times the ratio above which a run is noted as slower."""
    if delta.tolerance is None:
        return "-"
    if delta.spec.timing:
        return f"note > {1 + delta.tolerance:g}×"
    return f"±{delta.tolerance:g}"


def format_status(delta: Delta) -> str:
    """'ok', 'CHANGED (better)', 'CHANGED (worse)', 'info', 'info: slower' (times), 'new', 'MISSING'."""
    if delta.status == CHANGED:
        return f"CHANGED ({delta.direction})"
    if delta.spec.timing:
        return "info: slower" if delta.slower else "info"
    return delta.status


def describe_time(delta: Delta) -> str:
    """e.g. '1.05× the baseline after calibration' or '6.70× the baseline (uncalibrated)'."""
    if delta.ratio is None:
        return "no baseline time"
    return f"{delta.ratio:.2f}× the baseline" + (" after calibration" if delta.calibrated else " (uncalibrated)")


def format_table(deltas: list[Delta]) -> str:
    """The compared metrics and the times as a fixed-width table (metrics without a tolerance are left out)."""
    rows = [("run", "metric", "baseline", "current", "delta", "tolerance", "status")]
    rows += [(d.run, d.label, format_value(d, d.baseline), format_value(d, d.current), format_change(d),
              format_allowed(d), format_status(d)) for d in deltas if d.status != INFO or d.spec.timing]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    align = ["<", "<", ">", ">", ">", ">", "<"]
    return "\n".join("  ".join(f"{cell:{a}{w}}" for cell, a, w in zip(row, align, widths, strict=True)).rstrip()
                     for row in rows)


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: value}


def current_option_names(options: dict[str, Any]) -> dict[str, Any]:
    """metrics.json's ``options`` block with every former option name replaced by today's (``Options`` aliases), so
    that a renamed option is not reported as changed."""
    out = PipelineOptions.current_names({k: v for k, v in options.items() if k != "scene"})
    if isinstance(options.get("scene"), dict):
        out = {"scene": SceneOptions.current_names(options["scene"]), **out}
    return out


def option_changes(current: dict[str, Any], baseline: dict[str, Any] | None) -> list[str]:
    """'patchmatch.iterations: None -> 1' for every option that differs from the baseline's (under today's names)."""
    if not baseline:
        return []
    now = _flatten(current_option_names(current.get("options", {})))
    before = _flatten(current_option_names(baseline.get("options", {})))
    return [f"{k}: {before.get(k, '(absent)')} -> {now.get(k, '(absent)')}"
            for k in sorted(set(now) | set(before)) if now.get(k) != before.get(k)]
