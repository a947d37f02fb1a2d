"""Fusion settings for refined maps: why the ``refined`` preset keeps points seen by 2 pixels at 5°.

    .venv/bin/python benchmarks/experiments/refined_fusion_sweep.py RUN_DIR [RUN_DIR ...] \
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

from engine.fusion import FUSION_PRESETS
from engine.run.folder import read_metrics
from engine.scene import SceneOptions, load_scene
from support import bench
from support.scoring import fuse_and_score, pipeline_maps

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"runs": list}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt", "deepc_refined.pt")



def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x]


def sweep(run_dir: Path, tau: float, angles, min_pixels, reproj) -> dict:
    metrics = read_metrics(run_dir)
    scene = load_scene(metrics["scene_path"], SceneOptions.from_dict(metrics["options"]["scene"]))
    maps = pipeline_maps(scene, run_dir, full_tau=tau)
    if "full" not in maps:
        raise SystemExit(f"{run_dir}: refined maps missing; run refine_run / table3_refinement.py --weights first")
    rows = [{"maps": "fast (vanilla, conf 0.05)", "preset": "deepc", **FUSION_PRESETS["deepc"].to_dict(),
             **fuse_and_score(scene, *maps["fast"], FUSION_PRESETS["deepc"])}]
    full_d, full_n = maps["full"]
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


def summary(result: dict) -> list[dict]:
    """Per scene and fusion setting: F1, completeness and accuracy at 2 cm, F1 at 5 cm."""
    return [{"scene": res["scene"], "maps": r["maps"], "normal °": r["max_normal_error"],
             "min px": r["min_num_pixels"], "reproj px": r["max_reproj_error"], "F1 2 cm": r["f1@0.02"],
             "compl. 2 cm": r["completeness@0.02"], "acc. 2 cm": r["accuracy@0.02"], "F1 5 cm": r["f1@0.05"]}
            for res in result["runs"] for r in res["rows"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--tau", type=float, default=0.05)
    parser.add_argument("--angles", type=_floats, default=[5.0, 10.0, 20.0])
    parser.add_argument("--min-pixels", type=_floats, default=[2, 3])
    parser.add_argument("--reproj", type=_floats, default=[1.0])
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    results = [sweep(r, args.tau, args.angles, args.min_pixels, args.reproj) for r in args.runs]
    print(f"\n{'scene':<14} {'maps':<30} {'normal':>6} {'min_px':>6} {'reproj':>6} {'F1 2cm':>7} {'compl.':>7} "
          f"{'acc.':>6} {'F1 5cm':>7} {'points':>9}")
    for res in results:
        for r in res["rows"]:
            print(f"{res['scene']:<14} {r['maps']:<30} {r['max_normal_error']:>5.0f}° {r['min_num_pixels']:>6} "
                  f"{r['max_reproj_error']:>6.1f} {r['f1@0.02']:>7.2f} {r['completeness@0.02']:>7.2f} "
                  f"{r['accuracy@0.02']:>6.2f} {r['f1@0.05']:>7.2f} {r['points']:>9,}")
    bench.write_result({"runs": results}, args.json)
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
