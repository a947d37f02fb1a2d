"""``deepc regress``: run a suite headless, compare every run with its baseline, print and report the deltas.

Exit 0 when nothing regressed, 1 when something did (named); a run without a baseline fails too (a suite
entry nobody has checked is not a passed check). ``--update-baseline`` rewrites the baselines instead
and exits 0. The HTML report (``workbench/regress/report/``) and ``summary.json`` go to ``--report``.
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
from workbench.regress.baselines import baseline_path, read_baseline, read_baseline_reason, update_baselines
from workbench.regress.comparison import INFO, METRIC_BY_NAME, compare, format_table, option_changes
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
    if args.record:
        print("--record: times are reported but not compared (recording slows the runs down)", file=sys.stderr)
    results = [run_and_compare(i, suite, spec, baseline_dir, report_dir, args.record)
               for i, spec in enumerate(suite.runs, 1)]

    deltas = [d for r in results for d in r.deltas]
    print(format_table(deltas))
    for result in results:
        changed = option_changes(result.metrics, result.baseline)
        if changed:
            print(f"note: {result.spec.key} ran with options that differ from its baseline's: {'; '.join(changed)}")
    if args.update_baseline:
        update_baselines(results, baseline_dir, env, getattr(args, "reason", None))

    summary = write_json(report_dir / "summary.json", {
        "suite": str(suite.path), "baseline_dir": str(baseline_dir), "updated_baseline": bool(args.update_baseline),
        "environment": env, "runs": [{"run": r.spec.key, "out_dir": str(r.out_dir), "flags": r.spec.flags,
                                      "has_baseline": r.baseline is not None,
                                      "deltas": [dataclasses.asdict(d) for d in r.deltas]} for r in results]})
    report = write_report(report_dir / "report.html", suite, results, env, baseline_dir, args.update_baseline)
    print(f"report: {report} (summary: {summary})")
    return 0 if args.update_baseline else verdict(results)


def run_and_compare(i: int, suite: Suite, spec: RunSpec, baseline_dir: Path, report_dir: Path,
                    record: bool) -> RunResult:
    """Run entry ``i`` of the suite, add its CPU seconds to its metrics.json and compare it with its baseline."""
    print(f"[{i}/{len(suite.runs)}] {spec.key} ...", file=sys.stderr, flush=True)
    load_before, cpu_before = os.getloadavg()[0], time.process_time()
    out_dir = report_dir / spec.scene / spec.pipeline
    metrics, recording = execute(spec, out_dir, record)
    cpu_seconds = metrics["seconds_cpu"] = time.process_time() - cpu_before
    write_metrics(out_dir, metrics)
    baseline = read_baseline(baseline_path(baseline_dir, spec))
    tolerances = spec.tolerances
    if record:  # logging every iteration costs time that the baseline's run did not spend
        tolerances = {k: None if METRIC_BY_NAME[k].relative else v for k, v in tolerances.items()}
    result = RunResult(spec, out_dir, metrics, baseline, compare(spec.key, metrics, baseline, tolerances),
                       (round(load_before, 2), round(os.getloadavg()[0], 2)), recording,
                       read_baseline_reason(baseline_path(baseline_dir, spec)))
    print(f"[{i}/{len(suite.runs)}] {spec.key}: {result.run.seconds['total']:.1f} s "
          f"({cpu_seconds:.1f} s CPU), {len(result.failures)} regressed", file=sys.stderr, flush=True)
    return result


def verdict(results: list[RunResult]) -> int:
    """Print what regressed (and which runs have no baseline); the exit status."""
    missing = [r.spec.key for r in results if r.baseline is None]
    failures = [d for r in results for d in r.failures]
    if missing or failures:
        for key in missing:
            print(f"no baseline: {key} (make one with deepc regress --update-baseline)")
        for d in failures:
            print(f"regressed: {d.explain()}")
        print(f"REGRESSION: {len(failures)} metric(s) regressed"
              + (f", {len(missing)} run(s) without a baseline" if missing else ""))
        return 1
    compared = sum(d.status != INFO for r in results for d in r.deltas)
    print(f"nothing regressed ({len(results)} runs, {compared} metrics compared)")
    return 0
