"""ROC-AUC of confidence-network variants on held-out scenes (the paper's loss / fusion ablation table).

    .venv/bin/python benchmarks/paper/confidence_auc_table.py --variant deepc=W1.pt --variant bce=W2.pt ... \
        --run fountain_p11=runs/fountain768 --run synth_01000=... [--out benchmarks/results/confidence_auc_table.json]

Each ``--run`` is a finished ``deepc run`` folder of a scene with GT depth that no variant was trained on
(whole scenes, never views of a training scene: the script refuses a run whose scene is in a variant's
training data). Labels follow SPEC.md §4.3; ROC-AUC ×100 pooled over all labelled pixels of the scene
(and the mean of the per-view AUCs), inference as ``--pipeline fast`` runs it (bf16 autocast, confidence 0
where the normal faces away from the camera); ``network_only`` holds the AUC without that rule.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from engine.confidence.apply import auc_report, predict_samples
from engine.confidence.data import load_run
from engine.confidence.inference import facing_away
from engine.confidence.options import ConfidenceOptions
from engine.confidence.weights import load_weights
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"variants": dict, "runs": dict, "refined_maps": bool}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt", "deepc_refined.pt")



def _pair(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=PATH, got {text!r}")
    return name, Path(path)


def summary(result: dict) -> list[dict]:
    """ROC-AUC x100 per weights variant and held-out scene (pooled over its labelled pixels)."""
    return [{"variant": name, **{scene: r["auc"] for scene, r in row["scenes"].items()},
             "mean all": row["mean_all"]} for name, row in result["variants"].items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", type=_pair, action="append", required=True, metavar="NAME=WEIGHTS.pt")
    parser.add_argument("--run", type=_pair, action="append", required=True, metavar="NAME=RUN_DIR")
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch's default)")
    parser.add_argument("--refined", action="store_true",
                        help="score on the runs' refined maps (RUN/refined/, labels against the refined depth): "
                             "the second network's task in --pipeline full")
    args = parser.parse_args()

    models = {name: load_weights(path) for name, path in args.variant}
    runs = {}
    for name, run in args.run:
        t = time.perf_counter()
        runs[name] = load_run(run, refined=args.refined)
        print(f"{name}: {len(runs[name])} views, labels in {time.perf_counter() - t:.0f} s", flush=True)
    table: dict = {"variants": {}, "runs": {name: str(path) for name, path in args.run}, "refined_maps": args.refined}
    for vname, model in models.items():
        trained_on = set(model.meta.get("train_data", []))
        row = {"weights": str(dict(args.variant)[vname]), "fusion": model.fusion,
               "loss": model.meta.get("options", {}).get("loss"), "epoch": model.meta.get("epoch"),
               "train_seconds": model.meta.get("train_seconds"), "scenes": {}}
        for rname, samples in runs.items():
            if samples[0].scene in trained_on:
                raise SystemExit(f"{vname} was trained on {samples[0].scene}: not a held-out scene")
            t = time.perf_counter()
            raw = predict_samples(model, samples, ConfidenceOptions(num_threads=args.threads, zero_backfacing=False))
            report = auc_report(samples, [np.where(facing_away(s.inputs), np.float32(0), c)
                                          for s, c in zip(samples, raw, strict=True)])
            report["network_only"] = auc_report(samples, raw)
            report["seconds"] = time.perf_counter() - t
            row["scenes"][rname] = report
            alone = report["network_only"]["auc"]
            print(f"{vname:<16} {rname:<14} AUC {report['auc']:6.2f} (network alone {alone:6.2f}, mean per view "
                  f"{report['auc_mean_per_view']:6.2f}, inliers {report['inlier_pct']:.1f}%)", flush=True)
        synthetic = [r["auc"] for n, r in row["scenes"].items() if n != "fountain_p11"]
        row["mean_synthetic"] = float(np.mean(synthetic)) if synthetic else None
        row["mean_all"] = float(np.mean([r["auc"] for r in row["scenes"].values()]))
        table["variants"][vname] = row
    names = list(runs)
    print(f"\nROC-AUC x100 (pooled over labelled pixels per scene; back-facing estimates at 0 as in --pipeline fast)"
          f"\n{'variant':<16}"
          + "".join(f"{n[:12]:>13}" for n in names) + f"{'mean synth':>12}{'mean all':>10}")
    for vname, row in table["variants"].items():
        ms = row["mean_synthetic"]
        print(f"{vname:<16}" + "".join(f"{row['scenes'][n]['auc']:>13.2f}" for n in names)
              + f"{ms if ms is not None else float('nan'):>12.2f}{row['mean_all']:>10.2f}")
    bench.write_result(table, args.out)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
