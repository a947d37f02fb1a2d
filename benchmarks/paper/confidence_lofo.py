"""Leave-one-family-out estimate of the confidence network: trained without a dataset family, scored on it.

    .venv/bin/python benchmarks/paper/confidence_lofo.py [--recipe engine/confidence/recipes/deepc_middle.toml] \
        [--data ../shared/data] [--cache runs/train_cache] [--folds /work/runs/lofo] [--seeds 0,1,2] \
        [--family hololens ...] [--synthetic 1000-1003] [--taus 0.05,0.1] \
        [--out benchmarks/results/confidence_lofo.json]

The scenes are every scene of the recipe (all its splits) and the held-out synthetic seeds, in six families:
middlebury_2014q, middlebury_2005_2006, middlebury_2003, hololens, fountain_p11 (the recipe's entry: 768 px, 5
sources) and synthetic (the recipe's seeds and ``--synthetic``); variants of one scene (the recipe's ``[data]
groups``) stay together. For each family F and seed, the recipe's network (its training options, sampling and
real share; the seed replaced) is trained on every scene of the other families except the validation scenes,
which pick the checkpoint: the recipe's validation scenes outside F (or the first of
:data:`FALLBACK_VALIDATION` outside F when none is left), with their variants. It is then scored on all of F's
scenes with benchmarks/paper/confidence_real.py's scoring (support/confidence_scores.py): the pooled ROC-AUC of
the network alone, and fused F1 / accuracy at 2 cm of the unfiltered maps (vanilla) against the maps filtered at
each τ (``fast``; the headline is the pipeline's default back-facing rule, off). Engine runs are the recipe's
cached ones (made when missing); the weights, history and scores of each fold are kept under ``--folds`` (outside
the repository) and reused, so an interrupted run goes on where it stopped. The JSON is written after every fold
(``complete`` says whether every fold of every seed is in it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import tomllib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from engine.confidence.options import ConfidenceOptions
from engine.confidence.weights import load_weights
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS
from engine.io.atomic import atomic_write_text
from engine.synthetic.dataset import training_scene_name
from engine.training.recipe import SceneEntry, load_recipe, parse_seeds
from support import bench
from support.confidence_scores import score_scene
from workbench.cli.train import recipe_run, train_scenes

# Top-level keys of this script's result JSON and their types (support/schema.py); the harness adds its own.
SCHEMA = {"recipe": str, "options": dict, "seeds": list, "taus": list, "headline": str, "preset": str,
          "folds": dict, "families": dict, "complete": bool}

RECIPE = Path("engine/confidence/recipes/deepc_middle.toml")
FAMILY_ORDER = ("middlebury_2014q", "middlebury_2005_2006", "hololens", "fountain_p11", "middlebury_2003",
                "synthetic")
# family of a scene folder's first component under the data root (any other folder is its own family)
FOLDER_FAMILY = {"hololens_000": "hololens"}
SYNTHETIC = "synthetic"
# checkpoint selection when the recipe's validation scenes all belong to the held-out family: the first of these
# outside it (not the case for deepc_middle.toml, whose validation scenes span two families)
FALLBACK_VALIDATION = ("Recycle", "Aloe")
VARIANT = "lofo"


@dataclasses.dataclass(frozen=True)
class Fold:
    """One held-out family: the scenes trained on, those that pick the checkpoint and those scored."""

    family: str
    train: tuple[SceneEntry, ...]
    validation: tuple[SceneEntry, ...]
    test: tuple[SceneEntry, ...]

    def names(self) -> dict[str, list[str]]:
        return {split: [e.run_name for e in getattr(self, split)] for split in ("train", "validation", "test")}


def family_of(entry: SceneEntry, data_root: Path) -> str:
    """``synthetic`` for a synthetic seed, else the scene's first folder under the data root
    (:data:`FOLDER_FAMILY` renames some)."""
    if entry.synthetic:
        return SYNTHETIC
    try:
        top = Path(entry.path).relative_to(data_root).parts[0]
    except ValueError:
        top = Path(entry.path).resolve().relative_to(Path(data_root).resolve()).parts[0]
    return FOLDER_FAMILY.get(top, top)


def make_folds(entries: Sequence[SceneEntry], families: dict[str, str], validation: Sequence[str],
               groups: Sequence[Sequence[str]], fallback: Sequence[str] = FALLBACK_VALIDATION) -> dict[str, Fold]:
    """One :class:`Fold` per family (``families``: scene name -> family) in :data:`FAMILY_ORDER`, then any other
    family by name. ``validation``: the recipe's validation scene names; ``groups``: variants of one scene, which
    must lie in one family and end up in one split."""
    by_name = {e.name: e for e in entries}
    for group in groups:
        present = [n for n in group if n in by_name]
        if len({families[n] for n in present}) > 1:
            raise ValueError(f"variants {', '.join(group)} belong to different families")
    mates = {n: set(g) for g in groups for n in g}
    order = [f for f in FAMILY_ORDER if f in families.values()]
    order += sorted(set(families.values()) - set(order))
    folds = {}
    for family in order:
        chosen = [n for n in validation if n in by_name and families[n] != family]
        if not chosen:
            chosen = [next(n for n in fallback if n in by_name and families[n] != family)]
        held = {m for n in chosen for m in mates.get(n, {n}) | {n} if m in by_name}
        folds[family] = Fold(family,
                             tuple(e for e in entries if families[e.name] != family and e.name not in held),
                             tuple(e for e in entries if e.name in held),
                             tuple(e for e in entries if families[e.name] == family))
    return folds


def recipe_folds(recipe, synthetic_seeds: Sequence[int]) -> dict[str, Fold]:
    """The folds of every scene of ``recipe`` (all splits, in order) and the held-out synthetic seeds."""
    entries = [e for split in ("train", "validation", "test") for e in recipe.scenes(split)]
    known = {e.name for e in entries}
    entries += [SceneEntry(training_scene_name(s), None, s, dict(recipe.engine)) for s in synthetic_seeds
                if training_scene_name(s) not in known]
    groups = tomllib.loads(Path(recipe.path).read_text()).get("data", {}).get("groups", [])
    families = {e.name: family_of(e, recipe.data_root) for e in entries}
    return make_folds(entries, families, [e.name for e in recipe.scenes("validation")], groups)


def headline_key(tau: float) -> str:
    """The ``fast`` row the fast pipeline's default options make (support/confidence_scores.py's key)."""
    return f"{'rule' if ConfidenceOptions().zero_backfacing else 'network'}@{tau}"


# ---- one fold ------------------------------------------------------------------------------------

def fold_identity(fold: Fold, options, seed: int, taus: Sequence[float], preset: str) -> dict:
    """What a fold's saved history and scores must have been made with to be reused (as JSON reads it back)."""
    return json.loads(json.dumps({"scenes": fold.names(), "seed": seed, "taus": list(taus), "preset": preset,
                                  "options": {k: v for k, v in options.to_dict().items() if k != "device"}}))


def run_fold(fold: Fold, recipe, seed: int, cache: Path, folder: Path, taus: Sequence[float],
             preset: str) -> dict:
    """Train (or reuse) the fold's network and score every scene of its family (or reuse the scores)."""
    options = recipe.options.replace(seed=seed).validate()
    identity = fold_identity(fold, options, seed, taus, preset)
    scores_path, weights = folder / "scores.json", folder / "weights.pt"
    if scores_path.is_file() and weights.is_file():
        saved = json.loads(scores_path.read_text())
        if saved.get("identity") == identity:
            print(f"[{fold.family} seed {seed}] reusing {scores_path}", flush=True)
            return saved["result"]
    folder.mkdir(parents=True, exist_ok=True)
    history_path = folder / "history.json"
    history = json.loads(history_path.read_text()) if history_path.is_file() else None
    if history is None or history.get("identity") != identity or not weights.is_file():
        t = time.perf_counter()
        history = train_scenes(list(fold.train), list(fold.validation), options, recipe.real_share, cache, weights,
                               folder / "checkpoint.pt", label=f"[{fold.family} seed {seed}]")
        history = {"identity": identity, "seconds": time.perf_counter() - t, **history}
        atomic_write_text(history_path, json.dumps(history, default=float))
    model = load_weights(weights)
    leaked = {e.name for e in (*fold.test, *fold.validation)} & set(model.meta.get("train_data", []))
    if leaked:
        raise SystemExit(f"[{fold.family} seed {seed}] trained on {', '.join(sorted(leaked))}: not held out")
    best = history["best"]
    result = {"best_epoch": best["epoch"], "validation_auc": best["score"],
              "validation_sets": {k: v["auc"] for k, v in best["validation"]["sets"].items()},
              "train_minutes": sum(h["train_seconds"] for h in history["history"]) / 60, "scenes": {}}
    for entry in fold.test:
        t = time.perf_counter()
        row = score_scene(recipe_run(entry, cache), {VARIANT: model}, list(taus), [False, True], preset, fusion=True,
                          exclude_ground=entry.name == "fountain_p11")
        result["scenes"][entry.run_name] = row
        print(f"[{fold.family} seed {seed}] {entry.run_name}: {scene_line(row, taus)} "
              f"({time.perf_counter() - t:.0f} s)", flush=True)
    atomic_write_text(scores_path, json.dumps({"identity": identity, "result": result}, default=float))
    return result


def scene_line(row: dict, taus: Sequence[float]) -> str:
    v = row["variants"][VARIANT]
    text = f"ROC-AUC {v['auc_network']:.2f}"
    if "vanilla" in row:
        text += f", F1@2cm vanilla {row['vanilla']['f1@0.02']:.2f}"
        for tau in taus:
            fast = v["fast"].get(headline_key(tau))
            if fast:
                text += f", fast@{tau} {fast['f1@0.02']:.2f}"
    return text


# ---- tables --------------------------------------------------------------------------------------

def scene_metrics(row: dict, taus: Sequence[float]) -> dict:
    """The numbers of one scored scene the tables use (None where a scene has no fusion rows)."""
    v = row["variants"][VARIANT]
    out = {"auc": v["auc_network"], "f1_vanilla": None, "acc_vanilla": None}
    if "vanilla" in row:
        out["f1_vanilla"], out["acc_vanilla"] = row["vanilla"]["f1@0.02"], row["vanilla"]["accuracy@0.02"]
    for tau in taus:
        fast = v["fast"].get(headline_key(tau))
        out[f"f1_fast@{tau}"] = fast["f1@0.02"] if fast else None
        out[f"acc_fast@{tau}"] = fast["accuracy@0.02"] if fast else None
    return out


def finite_mean(values) -> float | None:
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(values)) if values else None


def family_table(folds: dict, taus: Sequence[float]) -> dict:
    """Per family: the mean over its scenes for each seed done, the mean over seeds and the spread (max - min)
    over seeds, and the issue's targets on the mean (fast F1 within 1 point of vanilla at each τ; ROC-AUC >= 90
    on real families)."""
    table = {}
    for family, fold in folds.items():
        per_seed = {}
        for seed, done in fold["seeds"].items():
            rows = [scene_metrics(r, taus) for r in done["scenes"].values()]
            per_seed[seed] = {k: finite_mean([r[k] for r in rows]) for k in rows[0]} if rows else {}
        if not per_seed:
            continue
        keys = next(iter(per_seed.values())).keys()
        mean = {k: finite_mean([s[k] for s in per_seed.values()]) for k in keys}
        entry = {"scenes": len(fold["test"]), "seeds_done": sorted(per_seed, key=int), "per_seed": per_seed,
                 "mean": mean}
        if len(per_seed) > 1:
            entry["spread"] = {k: (max(vals) - min(vals)) if (vals := [s[k] for s in per_seed.values()
                                                                       if s[k] is not None]) else None
                               for k in keys}
        targets = {}
        for tau in taus:
            fast, vanilla = mean[f"f1_fast@{tau}"], mean["f1_vanilla"]
            targets[f"f1_fast@{tau}_within_1"] = None if fast is None or vanilla is None else fast >= vanilla - 1.0
        targets["auc_at_least_90"] = None if family == SYNTHETIC or mean["auc"] is None else mean["auc"] >= 90.0
        entry["targets"] = targets
        table[family] = entry
    return table


def summary(result: dict) -> list[dict]:
    """Per held-out family (mean over its scenes, then over the seeds done): ROC-AUC of the network alone and
    its spread over seeds, fused F1 and accuracy at 2 cm of vanilla and of fast at each τ."""
    taus = result["taus"]
    rows = []
    for family, entry in result["families"].items():
        m = entry["mean"]
        row = {"family": family, "scenes": entry["scenes"], "seeds": len(entry["seeds_done"]), "AUC": m["auc"],
               "AUC spread": entry.get("spread", {}).get("auc"), "F1 vanilla": m["f1_vanilla"]}
        for tau in taus:
            row[f"F1 fast {tau}"] = m[f"f1_fast@{tau}"]
            row[f"F1 spread {tau}"] = entry.get("spread", {}).get(f"f1_fast@{tau}")
        row["acc vanilla"] = m["acc_vanilla"]
        for tau in taus:
            row[f"acc fast {tau}"] = m[f"acc_fast@{tau}"]
        rows.append(row)
    return rows


def scene_rows(result: dict) -> list[dict]:
    """Per fold, seed and scored scene: ROC-AUC of the network alone, fused F1 at 2 cm of vanilla and fast."""
    taus = result["taus"]
    rows = []
    for family, fold in result["folds"].items():
        for seed, done in fold["seeds"].items():
            for scene, r in done["scenes"].items():
                m = scene_metrics(r, taus)
                rows.append({"family": family, "seed": int(seed), "scene": scene, "AUC": m["auc"],
                             "AUC off GT ground": r["variants"][VARIANT].get("auc_network_offground"),
                             "F1 vanilla": m["f1_vanilla"],
                             **{f"F1 fast {t}": m[f"f1_fast@{t}"] for t in taus}})
    return rows


def add_fold_arguments(parser: argparse.ArgumentParser, folds_help: str) -> None:
    """The options that name the folds and where their runs and trainings live (this script's and
    confidence_calibration.py's)."""
    parser.add_argument("--seeds", type=parse_seeds, default=[0], help="training seeds, e.g. 0-2")
    parser.add_argument("--family", action="append", default=None, help="only these held-out families")
    parser.add_argument("--recipe", type=Path, default=RECIPE)
    parser.add_argument("--folds", type=Path, default=Path("/work/runs/lofo"), help=folds_help)
    parser.add_argument("--data", type=Path, default=None, help="data root (default: the recipe's)")
    parser.add_argument("--cache", type=Path, default=Path("runs/train_cache"), help="as deepc train --cache")
    parser.add_argument("--synthetic", type=parse_seeds, default=parse_seeds("1000-1003"),
                        help="held-out synthetic seeds of the synthetic family")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")


def chosen_folds(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple:
    """(recipe, folds by family) that :func:`add_fold_arguments`' options name; torch set to ``--threads``."""
    import torch  # lazy: torch (only to set its threads)

    torch.set_num_threads(args.threads)
    recipe = load_recipe(args.recipe, args.data)
    folds = recipe_folds(recipe, args.synthetic)
    if args.family:
        unknown = set(args.family) - set(folds)
        if unknown:
            parser.error(f"unknown famil(ies) {', '.join(sorted(unknown))} (known: {', '.join(folds)})")
        folds = {f: fold for f, fold in folds.items() if f in args.family}
    return recipe, folds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_fold_arguments(parser, "weights, history and scores of each fold (outside the repository; reused)")
    parser.add_argument("--taus", default="0.05,0.1")
    parser.add_argument("--preset", choices=sorted(FUSION_PRESETS), default=DEFAULT_PRESET)
    parser.add_argument("--out", type=Path, default=bench.results_path(__file__))
    args = parser.parse_args()
    recipe, folds = chosen_folds(parser, args)
    taus = [float(t) for t in args.taus.split(",") if t]
    table = {"recipe": bench.scrub(str(args.recipe)),
             "options": {k: v for k, v in recipe.options.to_dict().items() if k not in ("seed", "device")},
             "seeds": args.seeds, "taus": taus, "headline": headline_key(taus[0]).split("@")[0],
             "preset": args.preset,
             "folds": {f: {**fold.names(), "seeds": {}} for f, fold in folds.items()}, "families": {},
             "complete": False}
    for seed in args.seeds:
        for family, fold in folds.items():
            t = time.perf_counter()
            done = run_fold(fold, recipe, seed, args.cache, args.folds / f"seed{seed}" / family, taus, args.preset)
            table["folds"][family]["seeds"][str(seed)] = done
            table["families"] = family_table(table["folds"], taus)
            table["complete"] = all(len(f["seeds"]) == len(args.seeds) for f in table["folds"].values())
            bench.write_result(table, args.out)
            print(f"[{family} seed {seed}] done in {time.perf_counter() - t:.0f} s; wrote {args.out}", flush=True)
            bench.print_table(summary(table), title="per held-out family so far")
    bench.print_table(scene_rows(table), title="per scene")
    bench.print_table(summary(table), title="per held-out family (mean over its scenes, then over seeds)")
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    np.seterr(invalid="ignore")
    main()
