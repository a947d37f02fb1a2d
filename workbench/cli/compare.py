"""``deepc compare RUN_A RUN_B [--scene SCENE] [--report DIR]``: two runs of one scene, pixel by pixel.

A run is a deepc run folder, a COLMAP dense workspace or an OpenMVS densify folder (``engine.compare.sources``).
Prints, per view and over all views, the share of the GT pixels each run has within 1 % of GT, the four cases
(A right and B wrong, B right and A wrong, both right, both wrong), and where GT is missing the share of the
pixels both runs cover where they disagree by more than 1 %; then both fused clouds' accuracy, completeness and
F1 at every tolerance where the scene has GT points (``--fuse``: also each run's maps fused by our fusion, so
both are scored through one fusion). ``--report DIR`` also writes ``report.html``,
``compare.json`` and the maps (``workbench.compare.report``).
"""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from engine.core.errors import DeepCError

if TYPE_CHECKING:
    from engine.compare.comparison import Comparison
    from engine.compare.pixels import PixelCounts

COLUMNS = (("gt", "GT px", "{:,}"), ("a_right", "A right %", "{:.2f}"), ("b_right", "B right %", "{:.2f}"),
           ("a_right_b_wrong", "A right B wrong %", "{:.2f}"),
           ("b_right_a_wrong", "B right A wrong %", "{:.2f}"),
           ("both_wrong", "both wrong %", "{:.2f}"), ("no_gt", "no-GT px", "{:,}"),
           ("disagree", "disagree %", "{:.2f}"))


def _row(label: str, counts: PixelCounts, width: int) -> str:
    shares = counts.shares()
    cells = []
    for key, title, form in COLUMNS:
        value = shares[key] if key in shares else getattr(counts, key)
        text = "-" if isinstance(value, float) and math.isnan(value) else form.format(value)
        cells.append(f"{text:>{len(title)}}")
    return f"{label:<{width}} " + " ".join(cells)


def _f1_lines(title: str, blocks: dict) -> list[str]:
    """F1 of A and B per tolerance and the change, under ``title`` (no lines when neither was scored)."""
    a, b = blocks["a"], blocks["b"]
    if not a and not b:
        return []
    lines = [f"{title + ' tolerance':>22} {'A F1 %':>8} {'B F1 %':>8} {'B - A':>7}"]
    for i, t in enumerate((a or b)["tolerances"]):
        fa, fb = (None if x is None else x["f1"][i] for x in (a, b))
        change = f"{fb - fa:+7.2f}" if fa is not None and fb is not None else f"{'-':>7}"
        lines.append(f"{t:>22g} {'-' if fa is None else f'{fa:.2f}':>8} {'-' if fb is None else f'{fb:.2f}':>8} "
                     f"{change}")
    return lines


def format_comparison(c: Comparison) -> str:
    """The terminal table of a comparison."""
    width = max(len("all views"), *(len(v.name) for v in c.views))
    lines = [f"A: {c.a.path} ({c.a.description})", f"B: {c.b.path} ({c.b.description})",
             f"scene {c.scene.name}: {len(c.views)} views compared, right = within {100 * c.tolerance:g} % of GT"]
    lines += [f"views with a map in {k} only: {', '.join(names)}" for k, names in (("A", c.only_a), ("B", c.only_b))
              if names]
    lines.append(f"{'view':<{width}} " + " ".join(title for _, title, _ in COLUMNS))
    lines += [_row(v.name, v.counts, width) for v in c.views]
    lines.append(_row("all views", c.total, width))
    lines += _f1_lines("fused", c.fused) + _f1_lines("our fusion", c.ours_fused)
    lines += [f"note: {n}" for n in c.fused_notes]
    return "\n".join(lines)


def add_compare_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_a", metavar="RUN_A", help="a deepc run, a COLMAP dense workspace or an OpenMVS "
                                                       "densify folder")
    parser.add_argument("run_b", metavar="RUN_B", help="the same kinds")
    parser.add_argument("--scene", metavar="SCENE", default=None,
                        help="the COLMAP workspace the runs are of (default: a deepc run's scene, else a foreign "
                             "run's own sparse/ and images/)")
    parser.add_argument("--maps", choices=("fused", "raw"), default="fused",
                        help="a deepc run's maps: those its pipeline fused (default) or PatchMatch's")
    parser.add_argument("--tolerance", type=float, default=1.0, metavar="PERCENT",
                        help="relative depth tolerance of 'right' and 'disagree' (default: 1)")
    parser.add_argument("--report", metavar="DIR", default=None,
                        help="also write DIR/report.html, DIR/compare.json and the maps DIR/maps/*.png")
    parser.add_argument("--views", type=int, default=4, metavar="N",
                        help="views whose maps the report shows, those where the runs differ most (default: 4)")
    parser.add_argument("--no-fused", action="store_true", help="do not score the runs' fused clouds")
    parser.add_argument("--fuse", action="store_true",
                        help="also fuse each run's depth and normal maps with our fusion (default options) and "
                             "score both clouds: one fusion for both runs' maps")


def tolerance_fraction(percent: float) -> float:
    """The ``--tolerance`` percentage as a fraction; one outside (0, 100) is a :class:`DeepCError`."""
    if not 0 < percent < 100:
        raise DeepCError(f"option --tolerance={percent:g}: a percentage above 0 and below 100")
    return percent / 100


def cmd_compare(args: argparse.Namespace) -> int:
    """Handler of ``deepc compare``."""
    tolerance = tolerance_fraction(args.tolerance)
    if args.views < 0:
        raise DeepCError(f"option --views={args.views}: a number of views, 0 or more")
    from engine.compare.comparison import compare_runs, reference_scene  # lazy: scenes, evaluation
    from engine.compare.sources import open_run  # lazy: the run readers (engine.run)

    a, b = open_run(args.run_a, args.maps), open_run(args.run_b, args.maps)
    scene = reference_scene(a, b, args.scene)
    comparison = compare_runs(a, b, scene, tolerance, evaluate_fused=not args.no_fused,
                              fuse_ours=args.fuse)
    print(format_comparison(comparison))
    if args.report:
        from workbench.compare.report import write_report  # lazy: matplotlib (the F1 plot)

        print(f"report: {write_report(args.report, comparison, args.views)}")
    return 0
