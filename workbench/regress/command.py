"""``deepc regress``: run a suite headless, compare every run with its baseline, print and report the deltas.

Exit 0 when no quality metric changed beyond its tolerance, 1 when one did, better or worse (named, with
its direction: an improvement nobody expected is checked like a loss); a run without a baseline fails too
(a suite entry nobody has checked is not a passed check). ``--update-baseline --reason TEXT`` rewrites the
baselines instead and exits 0. Times never fail: a calibration workload is timed before, between and after
the runs and each run's time is reported as a ratio to its baseline's, normalised by the two calibrations
(``workbench/regress/calibration.py``). The HTML report (``workbench/regress/report/``) and ``summary.json``
go to ``--report``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

from engine.core.errors import DeepCError
from engine.io.atomic import write_json
from engine.run.folder import write_metrics
from workbench.regress.baselines import (
    baseline_path,
    read_baseline,
    read_baseline_calibration,
    read_baseline_reason,
    update_baselines,
)
from workbench.regress.calibration import Calibration, measure, time_scales
from workbench.regress.comparison import (
    BETTER,
    INFO,
    METRIC_BY_NAME,
    WORSE,
    compare,
    describe_time,
    format_table,
    option_changes,
)
from workbench.regress.environment import environment
from workbench.regress.report.page import write_report
from workbench.regress.running import RunResult, execute, prepare_out_dir, warm_up
from workbench.regress.suite import DEFAULT_SUITE, RunSpec, Suite, load_suite

DEFAULT_REPORT = Path("runs/regress")


def cmd_regress(args: argparse.Namespace) -> int:
    if getattr(args, "reason", None) and not args.update_baseline:
        raise DeepCError("deepc regress: --reason says why baselines are remade; it needs --update-baseline")
    suite = load_suite(args.suite or DEFAULT_SUITE)
    baseline_dir = Path(args.baseline).resolve() if args.baseline else suite.baseline_dir
    report_dir = Path(args.report) if args.report else DEFAULT_REPORT
    for spec in suite.runs:  # refuse what would fail before spending minutes on the runs
        prepare_out_dir(report_dir / spec.scene / spec.pipeline)
        read_baseline(baseline_path(baseline_dir, spec))
    env = environment()
    print(f"suite {suite.name} ({suite.path}): {len(suite.runs)} runs, baselines in {baseline_dir}", file=sys.stderr)
    print(f"warm-up (numba compilation, not timed): {warm_up(suite.runs):.1f} s", file=sys.stderr)
    calibration = measure()
    print(f"calibration before the runs: {calibration.describe()}", file=sys.stderr)
    if args.record:
        print("--record: recording slows the runs down; their times say little", file=sys.stderr)
    results = []
    for i, spec in enumerate(suite.runs, 1):
        results.append(run_and_compare(i, suite, spec, baseline_dir, report_dir, args.record))
        calibration = calibration.merged(measure(repeats=1))  # samples the machine's load through the suite
    calibration = calibration.merged(measure())
    print(f"calibration (median of the repeats before, between and after the runs): {calibration.describe()}",
          file=sys.stderr)
    for result in results:  # the times, now that the calibration is complete
        result.deltas = compare(result.spec.key, result.metrics, result.baseline,
                                run_tolerances(result.spec, args.record),
                                time_scales(calibration, result.baseline_calibration))

    deltas = [d for r in results for d in r.deltas]
    print(format_table(deltas))
    print_times(results, calibration)
    for result in results:
        changed = option_changes(result.metrics, result.baseline)
        if changed:
            print(f"note: {result.spec.key} ran with options that differ from its baseline's: {'; '.join(changed)}")
    if args.update_baseline:
        update_baselines(results, baseline_dir, env, getattr(args, "reason", None), calibration)
    else:
        print_reasons(results)

    summary = write_json(report_dir / "summary.json", {
        "suite": str(suite.path), "baseline_dir": str(baseline_dir), "updated_baseline": bool(args.update_baseline),
        "environment": env, "calibration": calibration.to_dict(),
        "runs": [{"run": r.spec.key, "out_dir": str(r.out_dir), "flags": r.spec.flags,
                  "has_baseline": r.baseline is not None, "baseline_reason": r.baseline_reason,
                  "baseline_calibration": r.baseline_calibration.to_dict() if r.baseline_calibration else None,
                  "deltas": [dataclasses.asdict(d) for d in r.deltas]} for r in results]})
    report = write_report(report_dir / "report.html", suite, results, env, baseline_dir, args.update_baseline,
                          calibration=calibration)
    print(f"report: {report} (summary: {summary})")
    return 0 if args.update_baseline else verdict(results)


def run_tolerances(spec: RunSpec, record: bool) -> dict[str, float | None]:
    """The run's tolerances; with --record no time is marked as slower (logging every iteration costs time
    that the baseline's run did not spend)."""
    if not record:
        return spec.tolerances
    return {k: None if METRIC_BY_NAME[k].timing else v for k, v in spec.tolerances.items()}


def run_and_compare(i: int, suite: Suite, spec: RunSpec, baseline_dir: Path, report_dir: Path,
                    record: bool) -> RunResult:
    """Run entry ``i`` of the suite, add its CPU seconds to its metrics.json and compare it with its baseline."""
    print(f"[{i}/{len(suite.runs)}] {spec.key} ...", file=sys.stderr, flush=True)
    load_before, cpu_before = os.getloadavg()[0], time.process_time()
    out_dir = report_dir / spec.scene / spec.pipeline
    metrics, recording = execute(spec, out_dir, record)
    cpu_seconds = metrics["seconds_cpu"] = time.process_time() - cpu_before
    write_metrics(out_dir, metrics)
    path = baseline_path(baseline_dir, spec)
    baseline = read_baseline(path)
    result = RunResult(spec, out_dir, metrics, baseline, compare(spec.key, metrics, baseline,
                                                                 run_tolerances(spec, record)),
                       (round(load_before, 2), round(os.getloadavg()[0], 2)), recording,
                       read_baseline_reason(path), read_baseline_calibration(path))
    print(f"[{i}/{len(suite.runs)}] {spec.key}: {result.run.seconds['total']:.1f} s "
          f"({cpu_seconds:.1f} s CPU), {len(result.failures)} changed", file=sys.stderr, flush=True)
    return result


def print_times(results: list[RunResult], calibration: Calibration) -> None:
    """Each run's time and CPU time against its baseline's, calibrated where the baseline has a calibration."""
    print(f"times (information only; speed regressions are caught by benchmarks/performance/): calibration "
          f"{calibration.describe()}")
    for result in results:
        times = {d.metric: d for d in result.deltas if d.spec.timing}
        if "time" not in times and "cpu_time" not in times:
            continue
        words = [f"{name} {describe_time(times[metric])}" for metric, name in (("time", "time"),
                                                                               ("cpu_time", "CPU time"))
                 if metric in times]
        base = result.baseline_calibration
        print(f"  {result.spec.key}  {', '.join(words)}"
              + (f" (baseline calibration {base.describe()})" if base else " (its baseline has no calibration)"))


def print_reasons(results: list[RunResult]) -> None:
    """Why the baselines were last remade, once per reason."""
    reasons: dict[str, list[str]] = {}
    for result in results:
        if result.baseline_reason:
            reasons.setdefault(result.baseline_reason, []).append(result.spec.key)
    for reason, keys in reasons.items():
        print(f"baselines remade on purpose: {reason} [{', '.join(keys)}]")


def verdict(results: list[RunResult]) -> int:
    """Print what changed beyond tolerance, either way (and which runs have no baseline); the exit status."""
    missing = [r.spec.key for r in results if r.baseline is None]
    failures = [d for r in results for d in r.failures]
    if missing or failures:
        for key in missing:
            print(f"no baseline: {key} (make one with deepc regress --update-baseline --reason TEXT)")
        for d in failures:
            print(f"{'changed' if d.direction else 'missing'}: {d.explain()}")
        counts = {kind: sum(d.direction == kind for d in failures) for kind in (BETTER, WORSE)}
        gone = len(failures) - counts[BETTER] - counts[WORSE]
        print(f"CHANGED: {len(failures)} metric(s) beyond tolerance ({counts[BETTER]} better, {counts[WORSE]} worse"
              + (f", {gone} missing" if gone else "") + ")"
              + (f", {len(missing)} run(s) without a baseline" if missing else "")
              + "; if this is intended, remake the baselines with deepc regress --update-baseline --reason TEXT")
        return 1
    compared = sum(d.status != INFO for r in results for d in r.deltas)
    print(f"nothing changed ({len(results)} runs, {compared} metrics compared; times are information only)")
    return 0
