"""Ours against the OpenMVS peer pixel by pixel (``deepc compare``): per view, the share of GT pixels only ours,
only the peer, both or neither has within 1 % of GT; both fused clouds and both runs' maps fused by our fusion
scored; the peer's cloud scored by ``deepc eval`` beside the F1 its own run script reported.

    .venv/bin/python benchmarks/performance/compare_peer.py OURS_RUN PEER_DIR [--peer-json BENCH_PEER.json]
        [--json benchmarks/results/compare_peer_<scene>.json]

OURS_RUN is a ``deepc run`` folder, PEER_DIR an OpenMVS densify folder (``depthNNNN.dmap``, ``scene_dense.ply``)
of the same scene, e.g. ``work/peer_0`` of ``bench_peer.py --no-ours --work work``, whose result JSON
(``--peer-json``) holds the peer's F1 as that script scored it. The comparison is ``deepc compare OURS_RUN PEER_DIR
--fuse`` (A = ours, its fused maps; B = the peer's maps): its times are the pixel comparison with both fused clouds
scored (what ``deepc compare`` does by default) and, apart, our fusion of both runs' maps with its scoring.
``deepc eval``'s score of the peer's cloud uses the GT depth maps at ``deepc eval``'s own size for the
unobserved-space rule, the peer script's those at the run's working size: the two F1s differ by that alone.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from engine.compare.comparison import compare_runs, ours_fused_scores, reference_scene
from engine.compare.sources import open_run
from engine.evaluation import EvaluationOptions
from support import bench
from workbench.cli.eval import run_eval

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"scene": str, "size": list, "ours": dict, "peer": dict, "tolerance": float, "seconds": dict,
          "overall": dict, "views": list, "fused": dict, "ours_fused": dict, "notes": list,
          "peer_deepc_eval": dict, "peer_script_f1?": list}

CASE_COLUMNS = (("a_right_pct", "ours right %"), ("b_right_pct", "peer right %"),
                ("a_right_b_wrong_pct", "only ours %"), ("b_right_a_wrong_pct", "only peer %"),
                ("both_wrong_pct", "both wrong %"), ("disagree_pct", "disagree (no GT) %"))


def summary(result: dict) -> list[dict]:
    """One row per view and one for all views: the share of GT pixels (percent) each run has within the tolerance
    of GT, only ours / only the peer has, neither has; and where GT is missing the share where the two disagree."""
    rows = []
    for label, counts in [*((v["view"], v) for v in result["views"]), ("all views", result["overall"])]:
        rows.append({"view": label, **{title: counts[key] for key, title in CASE_COLUMNS}})
    return rows


def _viewer_open_seconds(ours: Path, peer: Path) -> float:
    """Seconds ``deepc view OURS --compare PEER`` takes from its start to a viewer ready to interact: the runs
    opened and compared pixel by pixel, the clouds and colourings made, the server up (the fused clouds' scores
    arrive after it; the browser's drawing is not counted)."""
    from workbench.viewer.compare import CompareApp, open_comparison

    start = time.perf_counter()
    app = CompareApp(open_comparison(ours, peer, evaluate_fused=False), port=0, score_fused=True)
    seconds = time.perf_counter() - start
    app.wait_scored(600)
    app.stop()
    return seconds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ours", type=Path, help="a deepc run folder")
    ap.add_argument("peer", type=Path, help="an OpenMVS densify folder of the same scene")
    ap.add_argument("--peer-json", type=Path, default=None,
                    help="bench_peer.py's result of the run that made PEER_DIR (its peer F1 is recorded beside ours)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    options = EvaluationOptions()
    start = time.perf_counter()
    a, b = open_run(args.ours), open_run(args.peer)
    scene = reference_scene(a, b)
    comparison = compare_runs(a, b, scene, options=options)
    compare_s = time.perf_counter() - start
    start = time.perf_counter()
    ours_fused, fuse_notes = ours_fused_scores(a, b, scene, options)
    fuse_s = time.perf_counter() - start
    if b.fused is None:
        raise SystemExit(f"{args.peer}: no dense cloud (*_dense.ply)")
    start = time.perf_counter()
    peer_eval = run_eval(b.fused, scene.gt_points_path, options).to_dict()
    eval_s = time.perf_counter() - start
    viewer_s = _viewer_open_seconds(args.ours, args.peer)
    summary_dict = comparison.to_dict()
    result = {"scene": scene.name, "size": list(scene.views[0].camera.size), "ours": summary_dict["a"],
              "peer": summary_dict["b"], "tolerance": comparison.tolerance,
              "seconds": {"compare": compare_s, "our_fusion": fuse_s, "peer_deepc_eval": eval_s,
                          "viewer_open": viewer_s},
              "overall": summary_dict["overall"], "views": summary_dict["views"], "fused": comparison.fused,
              "ours_fused": ours_fused, "notes": comparison.fused_notes + fuse_notes, "peer_deepc_eval": peer_eval}
    if args.peer_json is not None:
        peer_result = json.loads(args.peer_json.read_text())
        result["peer_script_f1"] = [{"tolerances": peer_result["tolerances"], "f1": run["f1"]}
                                    for run in peer_result["runs"]["peer"]]
    path = bench.write_result(result, args.json or bench.results_path(__file__, scene.name))
    bench.print_table(summary(result))
    for title, blocks in (("fused", comparison.fused), ("our fusion", ours_fused)):
        for side, name in (("a", "ours"), ("b", "peer")):
            block = blocks[side]
            if block:
                print(f"{title} F1, {name}: " + " / ".join(f"{f:.2f}" for f in block["f1"])
                      + f" at {block['tolerances']} m")
    print("peer cloud, deepc eval F1: " + " / ".join(f"{f:.2f}" for f in peer_eval["f1"]))
    for run in result.get("peer_script_f1", []):
        print(f"peer cloud, bench_peer.py F1: {run['f1']} at {run['tolerances']} m")
    print(f"deepc compare {compare_s:.1f} s, our fusion of both {fuse_s:.1f} s, the compare viewer open in "
          f"{viewer_s:.1f} s; wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
