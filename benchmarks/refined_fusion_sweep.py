"""Fusion settings for refined maps: why the ``refined`` preset keeps points seen by 2 pixels at 5°.

    .venv/bin/python benchmarks/refined_fusion_sweep.py RUN_DIR [RUN_DIR ...] \
        [--tau 0.05] [--angles 5,10,20] [--min-pixels 2,3] [--reproj 1] [--json OUT.json]

RUN_DIR is a finished vanilla run whose refined maps exist (``refine_run`` / ``table3_refinement.py
--weights``). For each run: the fast pipeline's cloud (vanilla maps, network 1, τ 0.05, preset deepc) and the
full pipeline's maps (refined maps, second network at ``--tau``, sky filter) fused with every combination of
normal threshold, min_num_pixels and reprojection error; F1 / completeness / accuracy at 2 and 5 cm.
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

from table3_refinement import _network_confidence, fuse_and_score

from engine.confidence.weights import DEFAULT_REFINED_WEIGHTS, DEFAULT_WEIGHTS
from engine.filtering import filter_by_confidence
from engine.fusion import FUSION_PRESETS
from engine.io.outputs import read_map, write_json
from engine.refinement.views import sky_filter_views
from workbench.session import ViewerSession


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x]


def sweep(run_dir: Path, tau: float, angles, min_pixels, reproj) -> dict:
    session = ViewerSession.open(run_dir)
    scene, data = session.scene, session.data
    names = [v.name for v in scene.views]
    conf1 = _network_confidence(scene, [d.depth for d in data], [d.normal for d in data],
                                [d.counter for d in data], DEFAULT_WEIGHTS)
    refined = [(read_map(run_dir, "refined_depth", n), read_map(run_dir, "refined_normal", n),
                read_map(run_dir, "refined_counter", n)) for n in names]
    if any(m is None for r in refined for m in r):
        raise SystemExit(f"{run_dir}: refined maps missing; run refine_run / table3_refinement.py --weights first")
    conf2 = _network_confidence(scene, [r[0] for r in refined], [r[1] for r in refined], [r[2] for r in refined],
                                DEFAULT_REFINED_WEIGHTS)
    fast = [filter_by_confidence(d.depth, d.normal, c, 0.05) for d, c in zip(data, conf1, strict=True)]
    rows = [{"maps": "fast (vanilla, conf 0.05)", "preset": "deepc", **FUSION_PRESETS["deepc"].to_dict(),
             **fuse_and_score(scene, [x[0] for x in fast], [x[1] for x in fast], FUSION_PRESETS["deepc"])}]
    kept = [filter_by_confidence(r[0], r[1], c, tau) for r, c in zip(refined, conf2, strict=True)]
    full_d, full_n, _ = sky_filter_views(scene, [x[0] for x in kept], [x[1] for x in kept],
                                         [d.depth for d in data], conf1)
    for angle, min_px, rep in itertools.product(angles, min_pixels, reproj):
        options = FUSION_PRESETS["refined"].replace(max_normal_error=angle, min_num_pixels=int(min_px),
                                                    max_reproj_error=rep)
        rows.append({"maps": f"full (refined, conf {tau}, sky)", "preset": "custom", **options.to_dict(),
                     **fuse_and_score(scene, full_d, full_n, options)})
        r = rows[-1]
        print(f"  {scene.name:<14} {angle:>4.0f}° min_px {int(min_px)} reproj {rep:.1f}: F1 {r['f1@0.02']:6.2f} "
              f"compl. {r['completeness@0.02']:6.2f} acc. {r['accuracy@0.02']:6.2f} | 5 cm F1 {r['f1@0.05']:6.2f}"
              f"  (fast {rows[0]['f1@0.02']:.2f} | {rows[0]['f1@0.05']:.2f})", flush=True)
    return {"scene": scene.name, "run": str(run_dir), "tau": tau, "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--tau", type=float, default=0.05)
    parser.add_argument("--angles", type=_floats, default=[5.0, 10.0, 20.0])
    parser.add_argument("--min-pixels", type=_floats, default=[2, 3])
    parser.add_argument("--reproj", type=_floats, default=[1.0])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    results = [sweep(r, args.tau, args.angles, args.min_pixels, args.reproj) for r in args.runs]
    print(f"\n{'scene':<14} {'maps':<30} {'normal':>6} {'min_px':>6} {'reproj':>6} {'F1 2cm':>7} {'compl.':>7} "
          f"{'acc.':>6} {'F1 5cm':>7} {'points':>9}")
    for res in results:
        for r in res["rows"]:
            print(f"{res['scene']:<14} {r['maps']:<30} {r['max_normal_error']:>5.0f}° {r['min_num_pixels']:>6} "
                  f"{r['max_reproj_error']:>6.1f} {r['f1@0.02']:>7.2f} {r['completeness@0.02']:>7.2f} "
                  f"{r['accuracy@0.02']:>6.2f} {r['f1@0.05']:>7.2f} {r['points']:>9,}")
    if args.json:
        write_json(args.json, {"runs": results})
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
