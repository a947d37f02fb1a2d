"""Score a fountain_p11 run under the rule the OpenMVS peer numbers were measured with.

    .venv/bin/python benchmarks/performance/peer_fountain.py RUN_DIR [--out benchmarks/results/peer_fountain.json]
        [--fuse PRESET]

``--fuse PRESET`` scores the run's PatchMatch maps fused again with that preset of
``engine.fusion.FUSION_PRESETS`` (vanilla maps; the run's own fused.ply otherwise): what ``deepc run
--pipeline vanilla --fusion-preset PRESET`` would write, without running PatchMatch again.

Rule (issue 4): every valid GT depth pixel of every view (at the run's resolution) is a GT point, and
reconstructed points that no GT view observes are ignored (the unobserved-space rule with the GT depth
maps). Also reports the score against the scene's points.ply as `deepc run` / `deepc eval` compute it.
The peer's own numbers are not this script's: they come from peer runs made by
benchmarks/performance/bench_peer.py, which records the peer's build and command line.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from engine.evaluation import EvaluationOptions, evaluate_points
from engine.fusion import FUSION_PRESETS, fuse, read_fused_ply, views_from_scene
from engine.run.folder import read_map, read_metrics
from engine.run.pipeline import evaluate_cloud
from engine.scene import SceneOptions, load_scene
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "run": str, "fusion": dict, "points": int, "peer rule (GT depth pixels)": dict,
          "points.ply + unobserved rule": dict, "depth?": dict}


RULES = ("peer rule (GT depth pixels)", "points.ply + unobserved rule")


def summary(result: dict) -> list[dict]:
    """F1, accuracy and completeness at 2 / 5 cm of the run under both rules."""
    return [{"cloud": f"ours, {name}", "F1 2 / 5 cm": result[name]["f1"], "accuracy": result[name]["accuracy"],
             "completeness": result[name]["completeness"]} for name in RULES]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    parser.add_argument("--fuse", choices=sorted(FUSION_PRESETS), default=None, metavar="PRESET")
    args = parser.parse_args()
    metrics = read_metrics(args.run)
    scene = load_scene(metrics["scene_path"], SceneOptions.from_dict(metrics["options"]["scene"]))
    if args.fuse is None:
        cloud = read_fused_ply(args.run / "fused.ply")
        fusion = metrics["options"]["fusion"]
    else:
        names = [v.name for v in scene.views]
        maps = [(read_map(args.run, "depth", n), read_map(args.run, "normal", n)) for n in names]
        if any(d is None or n is None for d, n in maps):
            raise SystemExit(f"{args.run}: depth or normal maps missing")
        options = FUSION_PRESETS[args.fuse]
        cloud = fuse(views_from_scene(scene, [d for d, _ in maps], [n for _, n in maps], None,
                                      options.check_num_images), options)
        fusion = {"preset": args.fuse, **options.to_dict()}
    gt_views = scene.gt_views()
    gt_points = np.concatenate([cam.backproject(depth)[depth > 0] for cam, depth in gt_views])
    options = EvaluationOptions(tolerances=(0.02, 0.05))
    peer_rule = evaluate_points(np.asarray(cloud.xyz, np.float64), gt_points, options, gt_views)
    points_ply = evaluate_cloud(scene, cloud, options)
    rows = dict(zip(RULES, (peer_rule, points_ply), strict=True))
    print(f"{scene.name} {scene.views[0].camera.width}x{scene.views[0].camera.height}, {len(cloud):,} points, "
          f"{len(gt_points):,} GT depth points")
    print(f"{'':<30} {'F1 2cm':>7} {'F1 5cm':>7} {'acc 2':>6} {'acc 5':>6} {'comp 2':>7} {'comp 5':>7}")
    out = {"scene": scene.name, "run": str(args.run), "fusion": fusion, "points": len(cloud)}
    for name, r in rows.items():
        print(f"{name:<30} {r.f1[0]:>7.1f} {r.f1[1]:>7.1f} {r.accuracy[0]:>6.1f} {r.accuracy[1]:>6.1f} "
              f"{r.completeness[0]:>7.1f} {r.completeness[1]:>7.1f}")
        out[name] = r.to_dict()
    bench.write_result(out, args.out)


if __name__ == "__main__":
    main()
