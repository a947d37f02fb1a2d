"""A run's metrics against its baseline: the compared metrics, their tolerances, the deltas and how they read.

Every metric with a tolerance is compared with the baseline; it regresses when it is worse by more than
the tolerance (higher is better except ``abs_rel`` and ``time``). F1, accuracy and completeness are
compared at *every* tolerance of the evaluation, not only at the 2 cm / 5 cm headline ones: the runs are
deterministic for a seed, so each of them is exact and a loss at a fine tolerance (precision) is a real
regression even when the coarse ones hide it. ``time`` is the wall-clock total of the run and ``cpu_time``
its CPU seconds over all threads (``seconds_cpu``, added to metrics.json by regress: on a shared machine
the wall clock follows the other jobs' load, CPU time hardly does); only slower regresses.

Both sides of a comparison are metrics.json dicts: the current run's and the one stored in its baseline
file (``workbench/regress/baselines.py``), which has the same keys.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

#: (row label, value) pairs a metric reads from a metrics.json dict; several for per-tolerance scores
MetricValues = Callable[[dict[str, Any]], list[tuple[str, float | None]]]


@dataclasses.dataclass(frozen=True)
class MetricSpec:
    """A compared metric: how to read it from metrics.json and which direction is worse.

    ``relative``: the tolerance is a fraction of the baseline value (time) instead of points.
    ``values(metrics)`` returns (row label, value) pairs; several for per-tolerance scores.
    """

    name: str
    description: str
    higher_is_better: bool
    relative: bool
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
    MetricSpec("within_5pct", "PatchMatch depth within 5 % of GT (%)", True, False, None,
               _nested_value("within_5pct", "depth", "within_5pct")),
    MetricSpec("valid_fraction", "GT pixels with a depth estimate (%)", True, False, None,
               _nested_value("valid_fraction", "depth", "valid_fraction")),
    MetricSpec("abs_rel", "mean relative depth error", False, False, None,
               _nested_value("abs_rel", "depth", "abs_rel")),
    MetricSpec("auc", "confidence ROC-AUC × 100", True, False, 0.5, _nested_value("auc", "confidence_auc")),
    MetricSpec("time", "wall-clock seconds of the run", False, True, 0.5, _nested_value("time", "seconds", "total")),
    MetricSpec("cpu_time", "CPU seconds of the run, all threads (hardly depends on the machine's load)", False, True,
               0.5, _nested_value("cpu_time", "seconds_cpu")),
)
METRIC_BY_NAME = {m.name: m for m in METRICS}
DEFAULT_TOLERANCES: dict[str, float | None] = {m.name: m.default_tolerance for m in METRICS}

OK, IMPROVED, REGRESSED, NEW, MISSING, INFO = "ok", "improved", "REGRESSED", "new", "MISSING", "info"
FAILED = (REGRESSED, MISSING)


@dataclasses.dataclass
class Delta:
    """One metric of one run against its baseline."""

    run: str
    metric: str
    label: str
    baseline: float | None
    current: float | None
    tolerance: float | None
    status: str

    @property
    def spec(self) -> MetricSpec:
        return METRIC_BY_NAME[self.metric]

    def change(self) -> float | None:
        """current - baseline (points), or the relative change for relative metrics."""
        if self.baseline is None or self.current is None:
            return None
        if self.spec.relative:
            return self.current / self.baseline - 1.0 if self.baseline > 0 else 0.0
        return self.current - self.baseline

    def explain(self) -> str:
        """e.g. 'tiny/vanilla f1@0.02 47.60 -> 45.70 (-1.90, allowed -0.5)'."""
        if self.status == MISSING:
            return f"{self.run} {self.label}: missing (baseline {format_value(self, self.baseline)})"
        return (f"{self.run} {self.label} {format_value(self, self.baseline)} -> {format_value(self, self.current)} "
                f"({format_change(self)}, allowed {format_allowed(self)})")


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def compare(run: str, current: dict[str, Any], baseline: dict[str, Any] | None,
            tolerances: dict[str, float | None]) -> list[Delta]:
    """Deltas of every metric the current run or its baseline reports."""
    deltas = []
    for spec in METRICS:
        tol = tolerances.get(spec.name)
        now = {label: _number(v) for label, v in spec.values(current)}
        before = {label: _number(v) for label, v in spec.values(baseline or {})}
        for label in list(now) + [k for k in before if k not in now]:
            b, c = before.get(label), now.get(label)
            delta = Delta(run, spec.name, label, b, c, tol, INFO)
            if tol is None:
                pass
            elif b is None:
                delta.status = NEW if c is not None else INFO
            elif c is None:
                delta.status = MISSING
            else:
                change = delta.change()
                worse = change if not spec.higher_is_better else -change
                # the small slack absorbs float noise in values that only went through JSON
                delta.status = REGRESSED if worse > tol + 1e-9 else IMPROVED if -worse > tol + 1e-9 else OK
            deltas.append(delta)
    return deltas


def format_value(delta: Delta, value: float | None) -> str:
    """A baseline or current value of ``delta``'s metric as the table and the report show it."""
    if value is None:
        return "-"
    if delta.spec.relative:
        return f"{value:.1f} s"
    if delta.metric == "abs_rel":
        return f"{value:.4f}"
    return f"{value:.2f}"


def format_change(delta: Delta) -> str:
    """The change of ``delta``, signed (percent for relative metrics)."""
    change = delta.change()
    if change is None:
        return "-"
    if delta.spec.relative:
        return f"{change * 100:+.0f}%"
    return f"{change:+.4f}" if delta.metric == "abs_rel" else f"{change:+.2f}"


def format_allowed(delta: Delta) -> str:
    """The tolerance of ``delta``, signed in the direction that is worse."""
    if delta.tolerance is None:
        return "-"
    sign = "-" if delta.spec.higher_is_better else "+"
    if delta.spec.relative:
        return f"{sign}{delta.tolerance * 100:g}%"
    return f"{sign}{delta.tolerance:g}"


def format_table(deltas: list[Delta]) -> str:
    """The compared metrics as a fixed-width table (metrics without a tolerance are left out)."""
    rows = [("run", "metric", "baseline", "current", "delta", "allowed", "status")]
    rows += [(d.run, d.label, format_value(d, d.baseline), format_value(d, d.current), format_change(d),
              format_allowed(d), d.status) for d in deltas if d.status != INFO]
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


def option_changes(current: dict[str, Any], baseline: dict[str, Any] | None) -> list[str]:
    """'patchmatch.iterations: None -> 1' for every option that differs from the baseline's."""
    if not baseline:
        return []
    now, before = _flatten(current.get("options", {})), _flatten(baseline.get("options", {}))
    return [f"{k}: {before.get(k, '(absent)')} -> {now.get(k, '(absent)')}"
            for k in sorted(set(now) | set(before)) if now.get(k) != before.get(k)]
