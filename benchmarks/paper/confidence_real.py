"""Confidence on real photographs: ROC-AUC and filtered fusion per scene of a training recipe's split.

    .venv/bin/python benchmarks/paper/confidence_real.py --recipe engine/confidence/recipes/deepc_middle.toml \
        --data ../shared/data --variant new=engine/confidence/weights/deepc_middle.pt --variant old=OLD.pt \
        [--split test] [--synthetic 1000-1003] [--taus 0.05,0.1,0.3,0.5] [--rule both|on|off] \
        [--preset pixels] [--out benchmarks/results/confidence_real_test.json]

For every scene of the chosen split(s) (its engine run is the recipe's cached one, made when missing) and
each weights variant: the pooled ROC-AUC ×100 of the network alone and with the back-facing rule
(``confidence.zero_backfacing``), then fusion of the unfiltered maps (vanilla), of the maps filtered at
each τ (``fast``), and with mask 1 / mask 2 (the paper's Table 2 rows), scored at 2 and 5 cm against the
scene's GT points. ``--synthetic`` adds held-out synthetic scenes (AUC only, they are not photographs).
Scene runs are named in the JSON, never their paths.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from engine.confidence.weights import load_weights
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS
from engine.synthetic.dataset import training_scene_name
from engine.training.recipe import SceneEntry, load_recipe, parse_seeds
from support import bench
from support.confidence_scores import score_scene
from workbench.cli.train import recipe_run

# Top-level keys of this script's result JSON and their types (support/schema.py; a key ending in "?"
# may be absent); the harness adds its own (script, argv, git, dirty, environment, inputs).
SCHEMA = {"variants": dict, "preset": str, "scenes": dict}
# The shipped networks this script runs by default: their sha256 is recorded with every result.
WEIGHTS = ("deepc_middle.pt", "deepc_refined.pt")


def print_scene(name: str, result: dict) -> None:
    print(f"\n{name} ({result['views']} views)")
    if "vanilla" in result:
        for key in ("vanilla", "mask1", "mask2"):
            r = result[key]
            print(f"  {key:<22} F1@2cm {r['f1@0.02']:6.2f} acc {r['accuracy@0.02']:6.2f} "
                  f"compl {r['completeness@0.02']:6.2f} | F1@5cm {r['f1@0.05']:6.2f}")
    for vname, row in result["variants"].items():
        print(f"  [{vname}] ROC-AUC network alone {row['auc_network']:6.2f}, with rule {row['auc_rule']:6.2f} "
              f"(inliers {row['inlier_pct']:.1f} %)")
        if "full" in result and vname == next(iter(result["variants"])):
            f = result["full"]
            for key in [k for k in f if k.startswith("refined") or k == "full"]:
                r = f[key]
                delta = r["f1@0.02"] - result["vanilla"]["f1@0.02"]
                print(f"  [{vname}] {key:<22} F1@2cm {r['f1@0.02']:6.2f} ({delta:+.2f}) "
                      f"acc {r['accuracy@0.02']:6.2f} compl {r['completeness@0.02']:6.2f} | F1@5cm {r['f1@0.05']:6.2f}")
            if "depth_refined" in f:
                print(f"  [{vname}] depth within 1 %: vanilla {f['depth_vanilla']['within_1pct']:.2f}, refined "
                      f"{f['depth_refined']['within_1pct']:.2f}, full {f['depth_full']['within_1pct']:.2f}; "
                      "refined-map ROC-AUC (network 2) "
                      f"{f['auc_refined']:.2f}")
        if "auc_network_offground" in row:
            print(f"  [{vname}] off the GT ground plane ({result['ground_pct']:.1f} % of the labels): network alone "
                  f"{row['auc_network_offground']:6.2f}, with rule {row['auc_rule_offground']:6.2f}")
        for key, r in row["fast"].items():
            delta = r["f1@0.02"] - result["vanilla"]["f1@0.02"]
            print(f"  [{vname}] conf {key:<14} F1@2cm {r['f1@0.02']:6.2f} ({delta:+.2f}) "
                  f"acc {r['accuracy@0.02']:6.2f} compl {r['completeness@0.02']:6.2f} | F1@5cm {r['f1@0.05']:6.2f} "
                  f"kept {r['pixels_kept_pct']:.1f} %")


CARD_MARK = "<!-- benchmarks/paper/confidence_real.py -->"


def card_section(table: dict, variant: str) -> str:
    """Markdown of one variant's results, for the model card (replaces an earlier section)."""
    keys = next((list(r["variants"][variant]["fast"]) for r in table["scenes"].values()
                 if r["variants"][variant]["fast"]), [])
    lines = [CARD_MARK, "", f"## Held-out scenes (`benchmarks/paper/confidence_real.py {' '.join(table['argv'])}`)", "",
             "ROC-AUC ×100 pooled over each scene's labelled pixels; fused F1 / accuracy at 2 cm with the "
             f"`{table['preset']}` preset, vanilla against filtered at each τ (`rule@τ`: with the back-facing "
             "rule, `network@τ`: without).", "",
             "| scene | AUC network | AUC rule | vanilla F1 / acc | " + " | ".join(keys) + " |",
             "|---|---|---|---|" + "---|" * len(keys)]
    for name, result in table["scenes"].items():
        row = result["variants"][variant]
        cells = [f"{row['auc_network']:.2f}", f"{row['auc_rule']:.2f}"]
        if "auc_network_offground" in row:
            cells = [f"{row['auc_network']:.2f} ({row['auc_network_offground']:.2f} off the GT ground)",
                     f"{row['auc_rule']:.2f} ({row['auc_rule_offground']:.2f})"]
        if "vanilla" in result:
            cells.append(f"{result['vanilla']['f1@0.02']:.2f} / {result['vanilla']['accuracy@0.02']:.2f}")
            cells += [f"{row['fast'][k]['f1@0.02']:.2f} / {row['fast'][k]['accuracy@0.02']:.2f}" for k in keys]
        else:
            cells += ["–"] * (1 + len(keys))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_card_section(card: Path, section: str) -> None:
    from engine.io.atomic import atomic_write_text

    text = card.read_text() if card.is_file() else ""
    head = text.split(CARD_MARK)[0].rstrip()
    atomic_write_text(card, (head + "\n\n" if head else "") + section)


def summary(result: dict) -> list[dict]:
    """Per held-out scene and weights variant: ROC-AUC of the network alone and with the back-facing rule, fused
    F1 at 2 cm of the unfiltered maps and of the maps filtered at the first τ, and of --pipeline full."""
    rows = []
    for scene, r in result["scenes"].items():
        for name, v in r["variants"].items():
            row = {"scene": scene, "variant": name, "AUC network": v["auc_network"], "AUC rule": v["auc_rule"],
                   "F1 2 cm vanilla": r["vanilla"]["f1@0.02"] if "vanilla" in r else None}
            first = next(iter(v["fast"]), None)
            row["F1 2 cm filtered"] = v["fast"][first]["f1@0.02"] if first else None
            row["at"] = first
            if "full" in r:
                row["F1 2 cm full"] = r["full"]["full"]["f1@0.02"]
            rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recipe", type=Path, required=True)
    parser.add_argument("--data", type=Path, default=None, help="data root (default: the recipe's)")
    parser.add_argument("--cache", type=Path, default=Path("runs/train_cache"), help="as deepc train --cache")
    parser.add_argument("--variant", action="append", required=True, metavar="NAME=WEIGHTS.pt")
    parser.add_argument("--split", action="append", choices=("train", "validation", "test"), default=None)
    parser.add_argument("--scene", action="append", default=None, help="only these scenes of the split(s)")
    parser.add_argument("--synthetic", type=parse_seeds, default=[], help="held-out synthetic seeds (AUC only)")
    parser.add_argument("--taus", default="0.05,0.1,0.3,0.5")
    parser.add_argument("--rule", choices=("both", "on", "off"), default="on",
                        help="fuse with the back-facing rule on, off or both")
    parser.add_argument("--preset", choices=sorted(FUSION_PRESETS), default=DEFAULT_PRESET)
    parser.add_argument("--auc-only", action="store_true", help="ROC-AUC only: no fusion rows")
    parser.add_argument("--full", type=Path, default=None, metavar="NET2.pt",
                        help="also what --pipeline full makes of each run: the first variant guides the refinement, "
                             "these weights score the refined maps")
    parser.add_argument("--exclude-ground", action="append", default=[], metavar="SCENE",
                        help="also score SCENE without its GT ground plane (fountain_p11: that GT lies 2-3 %% "
                             "too far, benchmarks/experiments/gt_photo_consistency.py)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--model-card", type=Path, default=None, metavar="CARD.md",
                        help="also write the first variant's table into this model card (replacing an earlier one)")
    args = parser.parse_args()

    recipe = load_recipe(args.recipe, args.data)
    models = {}
    for item in args.variant:
        name, _, path = item.partition("=")
        models[name] = load_weights(path)
    taus = [float(t) for t in args.taus.split(",") if t]
    rules = {"both": [False, True], "on": [True], "off": [False]}[args.rule]
    entries = [e for split in (args.split or ["test"]) for e in recipe.scenes(split)
               if args.scene is None or e.name in args.scene]
    entries += [SceneEntry(training_scene_name(s), None, s, dict(recipe.engine)) for s in args.synthetic]
    table = {"variants": {name: {"weights": Path(item.partition("=")[2]).name,
                                 "train_data": models[name].meta.get("train_data", [])}
                          for name, item in zip(models, args.variant, strict=True)},
             "preset": args.preset, "scenes": {}}
    for e in entries:
        for name, model in models.items():
            if e.name in model.meta.get("train_data", []):
                raise SystemExit(f"variant {name} was trained on {e.name}: not a held-out scene")
        run = recipe_run(e, args.cache)
        table["scenes"][e.run_name] = score_scene(run, models, taus, rules, args.preset,
                                                  fusion=not (e.synthetic or args.auc_only),
                                                  exclude_ground=e.name in args.exclude_ground,
                                                  full=(Path(args.variant[0].partition("=")[2]), args.full)
                                                  if args.full else None)
        print_scene(e.run_name, table["scenes"][e.run_name])
        bench.write_result(table, args.out)  # after every scene: a long benchmark leaves what it has
    if args.model_card:
        write_card_section(args.model_card, card_section({**table, "argv": bench.scrub(sys.argv[1:])},
                                                         next(iter(models))))
    bench.print_table(summary(table))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    np.seterr(invalid="ignore")
    main()
