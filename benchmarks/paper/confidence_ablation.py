"""Train the ablation variants of the confidence network with one equal budget (paper §5.2: DeepC loss vs
BCE vs weighted BCE, middle vs early fusion; plus the literal l2 reading of the DeepC loss).

    .venv/bin/python benchmarks/paper/confidence_ablation.py RUN [RUN ...] --validation RUN [...] \
        [--epochs 4 --steps-per-epoch 15 --out-dir runs/ablation] [--json benchmarks/results/confidence_ablation.json]

Loads the training and validation data once, then trains every variant with the same data, seed, crops,
schedule and budget (``deepc train`` options otherwise at their defaults); each variant's weights go to
OUT_DIR/<loss>_<fusion>.pt (resumable checkpoints beside them), the training histories to the JSON (rewritten
after every variant). Score the weights on held-out scenes with benchmarks/paper/confidence_auc_table.py.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from engine.confidence.data import load_run
from engine.training.trainer import TrainOptions, ValidationSet, train
from support import bench

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"train_data": list, "validation": dict, "variants": dict}


VARIANTS = (("deepc_squared", "middle"), ("bce", "middle"), ("wbce", "middle"), ("deepc_l2", "middle"),
            ("deepc_squared", "early"))


def summary(result: dict) -> list[dict]:
    """Per variant: best epoch, its validation ROC-AUC per set, training seconds."""
    rows = []
    for name, v in result["variants"].items():
        best = next((h for h in v["history"] if h["epoch"] == v["best_epoch"]), None)
        sets = best["validation"]["sets"] if best else {}
        rows.append({"variant": name, "best epoch": v["best_epoch"],
                     **{f"AUC {k}": s["auc"] for k, s in sets.items()}, "seconds": v["seconds"]})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--validation", nargs="*", type=Path, default=[])
    parser.add_argument("--validation-max-views", type=int, default=2)
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--steps-per-epoch", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out-dir", type=Path, default=Path("runs/ablation"), help="weights and checkpoints")
    parser.add_argument("--json", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()

    samples = [s for run in args.runs for s in load_run(run)]
    validation = []
    for run in args.validation:
        views = load_run(run)
        step = max(1, len(views) // max(1, args.validation_max_views))
        validation.append(ValidationSet(run.name, views[::step][:args.validation_max_views]))
    names = sorted({s.scene for s in samples})
    record = {"train_data": names, "validation": {v.name: [s.view for s in v.samples] for v in validation},
               "variants": {}}
    for loss, fusion in VARIANTS:
        name = f"{loss}_{fusion}"
        options = TrainOptions(loss=loss, fusion=fusion, epochs=args.epochs, steps_per_epoch=args.steps_per_epoch,
                               batch=4, crop=128, lr=1e-3, lr_final=3e-4, num_threads=args.threads, seed=0)
        t = time.perf_counter()

        def progress(event: dict, name: str = name) -> None:
            if event["kind"] == "epoch":
                aucs = ", ".join(f"{k} {v['auc']:.2f}" for k, v in event["validation"]["sets"].items())
                print(f"{name} epoch {event['epoch']}: loss {event['loss']:.4f}, ROC-AUC {aucs}", flush=True)

        result = train(samples, validation, options, args.out_dir / f"{name}.checkpoint.pt",
                       args.out_dir / f"{name}.pt", progress=progress, data_names=names)
        record["variants"][name] = {"options": options.to_dict(), "seconds": time.perf_counter() - t,
                                     "best_epoch": result["best"]["epoch"], "history": result["history"]}
        bench.write_result(record, args.json)
    bench.print_table(summary(record))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
