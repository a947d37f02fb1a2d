"""``deepc probe RUN_DIR --view V --pixel X,Y [...]``: why a depth is what it is, on a finished run.

Traces the pixels through every PatchMatch half-step of the run (``engine.run.probe.probe_run``: the view is
re-run alone from the run's pass history) and writes ``RUN_DIR/probes/<view>/<x>_<y>.json``
(docs/probe_schema.md). With ``--region X0,Y0,W,H`` it re-runs that box instead, from the state ``--level`` /
``--pass`` started from, with ``--set NAME=VALUE`` PatchMatch options changed, and prints the crop's error
before and after (``engine.run.probe.rerun_region``).
"""

from __future__ import annotations

import argparse
import json
import sys

from engine.core.errors import DeepCError
from engine.patchmatch import PatchMatchOptions
from workbench.flags.assignments import check_stages, section_overrides
from workbench.flags.run import parse_pixel


def add_probe_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``deepc probe``."""
    parser.add_argument("run_dir", metavar="RUN_DIR", help="output folder of a finished deepc run")
    parser.add_argument("--view", required=True, help="the view: its image name or its index")
    parser.add_argument("--pixel", action="append", default=[], metavar="X,Y",
                        help="a pixel to trace (column X, row Y at full resolution); up to 64")
    parser.add_argument("--region", metavar="X0,Y0,W,H", default=None,
                        help="re-run this box of the view (full resolution) instead of only tracing")
    parser.add_argument("--level", type=int, default=0, help="--region: the pyramid level to start at (0 = finest)")
    parser.add_argument("--pass", dest="pass_index", type=int, default=0,
                        help="--region: the pass of that level to start at (0 = photometric)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="--region: a PatchMatch option changed for the re-run, e.g. --set window=7 (the "
                             "patchmatch.* options of 'deepc run --help-options')")


def region_overrides(items: list[str]) -> dict[str, object]:
    """``--set NAME=VALUE`` items of ``deepc probe --region`` (PatchMatch options; ``patchmatch.NAME=VALUE`` too),
    typed by the parser of ``deepc run --set``."""
    check_stages(items, ("patchmatch",), unprefixed="patchmatch")
    return section_overrides(items, "patchmatch", PatchMatchOptions, unprefixed="patchmatch")


def cmd_probe(args: argparse.Namespace) -> int:
    from engine.run.probe import probe_run, rerun_region  # lazy: the engine pipeline
    from engine.run.probe_output import probe_path  # lazy: the engine pipeline

    pixels = [parse_pixel(p) for p in args.pixel]
    if args.region is None:
        if not pixels:
            raise DeepCError("deepc probe: give at least one --pixel X,Y (or --region X0,Y0,W,H)")
        traces = probe_run(args.run_dir, args.view, pixels)
        for t in traces:
            f = t["final"]
            print(f"{t['view']} ({t['x']}, {t['y']}): {len(t['iterations'])} half-steps, depth {f['depth']:.4g}"
                  + (f", GT {f['gt_depth']:.4g}, error {100 * f['error']:.2f}%" if f.get("error") is not None else "")
                  + f" -> {probe_path(args.run_dir, t['view'], t['x'], t['y'])}")
        return 0
    parts = args.region.split(",")
    try:
        box = tuple(int(p) for p in parts)
    except ValueError:
        box = ()
    if len(box) != 4:
        raise DeepCError(f"--region {args.region!r}: expected X0,Y0,W,H (four integers)")
    r = rerun_region(args.run_dir, args.view, box, args.level, args.pass_index, region_overrides(args.set), pixels)
    print(f"region {r.box} re-run in {r.seconds:.2f} s")
    if r.within_1pct_before is not None:
        print(f"within 1%: {r.within_1pct_before:.1f}% before, {r.within_1pct_after:.1f}% after")
    for t in r.traces:
        print(f"({t['x']}, {t['y']}): {len(t['iterations'])} half-steps, depth {t['final']['depth']:.4g}")
    print(json.dumps({"box": list(r.box), "within_1pct_before": r.within_1pct_before,
                      "within_1pct_after": r.within_1pct_after, "seconds": r.seconds}), file=sys.stderr)
    return 0
