"""The baseline files of ``deepc regress``: ``BASELINE/<scene>/<pipeline>.json``, read, written and remade.

A baseline file holds the run's key, its flags, its metrics.json dict (without the machine-specific
``scene_path``), where it was measured, the calibration measured in the same invocation (the time of a fixed
workload, ``workbench/regress/calibration.py``; baselines made before it have none) and, when remade with
``--reason``, why.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from engine.core.errors import DeepCError
from engine.io.atomic import write_json
from workbench.regress.calibration import Calibration
from workbench.regress.comparison import format_change, format_value
from workbench.regress.running import RunResult
from workbench.regress.suite import RunSpec


def baseline_path(baseline_dir: Path, spec: RunSpec) -> Path:
    return baseline_dir / spec.scene / f"{spec.pipeline}.json"


def read_baseline(path: Path) -> dict[str, Any] | None:
    """The metrics stored in a baseline file, or None when there is none."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        return dict(data["metrics"])
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise DeepCError(f"malformed baseline file ({exc}); remake it with --update-baseline", path) from None


def write_baseline(path: Path, spec: RunSpec, metrics: dict[str, Any], env: dict[str, Any],
                   load_average: tuple[float, float], reason: str | None = None,
                   calibration: Calibration | None = None) -> None:
    stored = {k: v for k, v in metrics.items() if k != "scene_path"}  # machine-specific
    write_json(path, {"run": spec.key, "flags": spec.flags, "metrics": stored,
                      "measured": {**env, "load_average_during_run": list(load_average)},
                      **({"calibration": calibration.to_dict()} if calibration else {}),
                      **({"reason": reason} if reason else {})})


def read_baseline_calibration(path: Path) -> Calibration | None:
    """The calibration stored with the baseline at ``path``; None when it has none (older baselines) or none
    that is comparable (another workload)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return Calibration.from_dict(data.get("calibration")) if isinstance(data, dict) else None


def read_baseline_reason(path: Path) -> str | None:
    """Why the baseline at ``path`` was remade, with its date and git revision; None when it does not say."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not data.get("reason"):
        return None
    measured = data.get("measured") or {}
    return f"{data['reason']} ({measured.get('date', 'date unknown')}, git {measured.get('git', 'unknown')})"


def baseline_changes(result: RunResult) -> str:
    """What --update-baseline changes for one run, in one line."""
    if result.baseline is None:
        return f"{result.spec.key}: new baseline"
    parts = []
    for d in result.deltas:
        change = d.change()
        if d.spec.timing:  # times always differ a little; they are shown below
            continue
        if d.baseline is None and d.current is not None:
            parts.append(f"{d.label} new {format_value(d, d.current)}")
        elif d.current is None and d.baseline is not None:
            parts.append(f"{d.label} removed")
        elif change is not None and abs(change) > 1e-9:
            parts.append(f"{d.label} {format_value(d, d.baseline)} -> {format_value(d, d.current)} "
                         f"({format_change(d)})")
    timing = [f"{d.label} {format_value(d, d.baseline)} -> {format_value(d, d.current)}" for d in result.deltas
              if d.spec.timing and d.baseline is not None and d.current is not None]
    return f"{result.spec.key}: " + "; ".join((parts or ["metrics unchanged"]) + timing)


def update_baselines(results: list[RunResult], baseline_dir: Path, env: dict[str, Any],
                     reason: str | None = None, calibration: Calibration | None = None) -> None:
    """Rewrite every run's baseline with its metrics and the invocation's calibration, and print what changed
    (and which files were left)."""
    for result in results:
        write_baseline(baseline_path(baseline_dir, result.spec), result.spec, result.metrics, env,
                       result.load_average, reason, calibration)
        result.baseline_reason = read_baseline_reason(baseline_path(baseline_dir, result.spec))
    print(f"baselines rewritten in {baseline_dir}" + (f", reason: {reason}" if reason else " (no --reason given)")
          + ":")
    for result in results:
        print(f"  {baseline_changes(result)}")
    current = {baseline_path(baseline_dir, r.spec) for r in results}
    for stale in sorted(set(baseline_dir.glob("*/*.json")) - current):
        print(f"  {stale.parent.name}/{stale.stem}: not in this suite, left as it was ({stale})")
