"""``deepc train``: run the engine on scenes with GT depth (cached), label the maps and train the
confidence network (engine/training/trainer.py), keeping the best checkpoint by validation ROC-AUC.

Positional arguments and ``--validation`` take scene folders (the engine is run on them once and the
run cached under ``--cache/runs/<scene>``) or finished run folders (``deepc run`` outputs, used as they
are). ``--synthetic SEEDS`` adds randomised synthetic scenes (engine/synthetic/dataset.py), rendered
into ``--cache/scenes`` when missing. ``--refined`` trains the second network of ``--pipeline full``: every
run is refined first (engine/run/refine.py, cached in RUN/refined/) and the network learns on the
refined maps. ``--recipe FILE`` takes all of that from a training recipe (engine/training/recipe.py) and
writes the weights with a model card (workbench/cli/model_card.py): how the shipped weights are made.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np

from engine.confidence.data import load_run
from engine.confidence.options import TrainOptions
from engine.core.errors import DeepCError
from engine.core.words import plural
from engine.io.atomic import atomic_write_text, write_json
from engine.patchmatch import PatchMatchOptions
from engine.run.folder import INFERENCE, POST_REFINEMENT, file_sha256
from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions
from engine.training.recipe import SceneEntry, load_recipe
from engine.training.runs import ensure_run
from workbench.cli.model_card import inputs_line, write_recipe_model_card
from workbench.flags.assignments import apply_assignments, split_item
from workbench.flags.options import given_flags, options_from_args
from workbench.flags.train import REFINE_SECTIONS


def refine_options(assignments: list[str]):
    """The :class:`PipelineOptions` of the full pipeline with ``--set`` overrides of :data:`REFINE_SECTIONS`."""
    for item in assignments:
        if split_item(item)[0] not in REFINE_SECTIONS:
            raise DeepCError(f"--set {item!r}: deepc train takes only the stages {', '.join(REFINE_SECTIONS)}")
    return apply_assignments(PipelineOptions(pipeline="full"), assignments)


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _resolve_runs(paths: list[str], seeds: list[int], cache: Path, scene_options, pipeline_options) -> list[Path]:
    from engine.synthetic.dataset import write_training_scenes  # lazy: pycolmap

    folders = [Path(p) for p in paths]
    if seeds:
        folders += write_training_scenes(cache / "scenes", seeds)
    runs = []
    for folder in folders:
        if not folder.is_dir():
            raise DeepCError("no such scene or run folder", folder)
        if (folder / "metrics.json").is_file():
            runs.append(folder)
        else:
            runs.append(ensure_run(folder, cache / "runs", scene_options, pipeline_options, log=_log))
    return runs


class Refiner:
    """Refines runs (or reuses their cached refined maps) with one network-1 weights file, loaded once."""

    def __init__(self, weights: str | None, options):
        from engine.confidence.weights import DEFAULT_WEIGHTS, load_weights  # lazy: torch

        self.weights = Path(weights).resolve() if weights else DEFAULT_WEIGHTS
        self.model = load_weights(self.weights)
        self.options = options
        self.sha256 = file_sha256(self.weights)

    def __call__(self, run: Path) -> None:
        from engine.run.refine import refine_run  # lazy: torch

        result = refine_run(run, self.weights, self.options, model=self.model,
                            log=lambda line: _log("  refining " + line))
        if result.reused:
            _log(f"{run}: cached refined maps reused (stamp matches)")
        else:
            s = result.seconds
            _log(f"{run}: {plural(result.views, 'view')} refined in {sum(s.values()):.0f} s (confidence "
                 f"{s['confidence']:.0f} s, refinement {s['refinement']:.0f} s, counter maps {s['counter']:.0f} s)")

    def description(self) -> dict:
        """What the training inputs are, for the checkpoint identity and the weights' meta."""
        confidence = self.options.confidence.to_dict()
        return {"maps": "refined", "refine_weights": str(self.weights), "refine_weights_sha256": self.sha256,
                "refinement": {k: v for k, v in self.options.refinement.to_dict().items() if k not in POST_REFINEMENT},
                "counter": self.options.counter.to_dict(), "confidence": {k: confidence[k] for k in INFERENCE}}


def _load(runs: list[Path], refiner: Refiner | None = None):
    samples = []
    for run in runs:
        if refiner is not None:
            refiner(run)
        samples.extend(load_run(run, refined=refiner is not None))
    return samples


def _subset(samples: list, count: int) -> list:
    if count <= 0 or len(samples) <= count:
        return samples
    return [samples[int(i)] for i in np.linspace(0, len(samples) - 1, count).round()]


def recipe_run(entry: SceneEntry, cache: Path) -> Path:
    """The cached engine run of one recipe scene (rendered first when synthetic)."""
    from engine.synthetic.dataset import write_training_scenes  # lazy: pycolmap

    folder = entry.path or write_training_scenes(cache / "scenes", [entry.seed])[0]
    scene_options = SceneOptions(num_source_views=entry.engine.get("num_source_views", 4),
                                 max_image_size=entry.engine.get("max_image_size", 0))
    pipeline_options = PipelineOptions(pipeline="vanilla", patchmatch=PatchMatchOptions(
        schedule=entry.engine.get("schedule", "acmm"), iterations=entry.engine.get("iterations"), seed=0)).validate()
    return ensure_run(folder, cache / "runs", scene_options, pipeline_options, log=_log, name=entry.run_name,
                      require_gt=False)


def train_scenes(train_entries: list[SceneEntry], validation_entries: list[SceneEntry], options: TrainOptions,
                 real_share: float, cache: Path, out: Path, checkpoint: Path, refiner: Refiner | None = None,
                 max_epochs: int | None = None, validation_max_views: int = 0, label: str = "training") -> dict:
    """Train on recipe scenes as ``deepc train --recipe`` does: each scene's cached engine run (:func:`recipe_run`),
    ``real_share`` of the crops from real views (uniformly over the views within real and within synthetic ones),
    one validation set per validation scene, the best weights to ``out``; resumable from ``checkpoint``. Returns
    the trainer's history with ``validation_sets`` (the views scored per set)."""
    from engine.training.trainer import ValidationSet, train  # lazy: torch

    t = time.perf_counter()
    train_samples, real = [], []  # real: one flag per training view
    for entry in train_entries:
        views = _load([recipe_run(entry, cache)], refiner)
        train_samples += views
        real += [not entry.synthetic] * len(views)
    real = np.asarray(real)
    real_views, synthetic_views = int(real.sum()), int((~real).sum())
    share = real_share if real_views and synthetic_views else float(real_views > 0)
    weights = np.where(real, share / max(1, real_views), (1 - share) / max(1, synthetic_views))
    validation = [ValidationSet(entry.name, _subset(_load([recipe_run(entry, cache)], refiner), validation_max_views))
                  for entry in validation_entries]
    labelled = sum(int((s.labels >= 0).sum()) for s in train_samples)
    maps = "refined" if refiner else "vanilla"
    _log(f"{label} ({maps} maps): {len(train_entries)} training scenes ({real_views} real views, "
         f"{synthetic_views} synthetic; {100 * share:.0f} % of crops from real views), {labelled:,} labelled "
         f"pixels; validation: {', '.join(v.name for v in validation) or 'none'} ({time.perf_counter() - t:.0f} s)")
    result = train(train_samples, validation, options, checkpoint, out, progress=_progress_logger(options, checkpoint),
                   data_names=sorted({s.scene for s in train_samples}), max_epochs=max_epochs,
                   probabilities=weights, inputs=refiner.description() if refiner else None)
    result["validation_sets"] = {v.name: [s.view for s in v.samples] for v in validation}
    return result


def cmd_train_recipe(args: argparse.Namespace) -> int:
    """``deepc train --recipe FILE``: the recipe's training and validation scenes, options and sampling."""
    if (args.scenes or args.synthetic or args.validation or args.validation_synthetic or args.refined
            or args.refine_weights or args.set or args.init):
        raise DeepCError("deepc train --recipe: the recipe names the scenes and maps; give no SCENE, --synthetic, "
                         "--validation, --refined, --refine-weights, --set or --init")
    recipe = load_recipe(args.recipe, args.data)
    refiner = None
    if recipe.refined is not None:
        refiner = Refiner(recipe.refined.get("weights") or None, refine_options(recipe.refined.get("set", [])))
    options: TrainOptions = recipe.options.replace(**given_flags(TrainOptions, args)).validate()
    cache = Path(args.cache)
    out = Path(args.out) if args.out else Path("runs/train") / recipe.name / f"{recipe.name}.pt"
    checkpoint = Path(args.checkpoint) if args.checkpoint else out.with_name(out.stem + ".checkpoint.pt")
    result = train_scenes(recipe.scenes("train"), recipe.scenes("validation"), options, recipe.real_share, cache,
                          out, checkpoint, refiner=refiner, max_epochs=args.max_epochs,
                          validation_max_views=args.validation_max_views, label=f"recipe {recipe.name}")
    result["recipe"] = {"name": recipe.name, "text": recipe.text}
    write_json(out.with_name(out.stem + ".history.json"), result)
    card = Path(args.model_card) if args.model_card else out.with_name("MODEL_CARD.md")
    write_recipe_model_card(card, out, result, recipe)
    best = result["best"]
    print(json.dumps({"weights": str(out), "model_card": str(card), "best_epoch": best["epoch"],
                      "score": best["score"], "epochs_done": result["epochs_done"]}))
    return 0


def _progress_logger(options, checkpoint: Path):
    start = time.perf_counter()

    def progress(event: dict) -> None:
        if event["kind"] == "resume":
            _log(f"resuming from {checkpoint} after epoch {event['epoch']}")
        elif event["kind"] == "step" and (event["step"] % 10 == 0 or event["step"] + 1 == event["steps"]):
            _log(f"epoch {event['epoch'] + 1}/{options.epochs} step {event['step'] + 1}/{event['steps']} "
                 f"loss {event['loss']:.4f} ({time.perf_counter() - start:.0f} s)")
        elif event["kind"] == "epoch":
            aucs = ", ".join(f"{k} {v['auc']:.2f}" for k, v in event["validation"]["sets"].items())
            _log(f"epoch {event['epoch']}: loss {event['loss']:.4f}, ROC-AUC {aucs or '-'}"
                 f"{' (best so far, saved)' if event['improved'] else ''}; train {event['train_seconds']:.0f} s, "
                 f"validation {event['validation_seconds']:.0f} s")
    return progress


def cmd_train(args: argparse.Namespace) -> int:
    if args.recipe:
        return cmd_train_recipe(args)
    if args.data:
        raise DeepCError("deepc train: --data only makes sense with --recipe")
    from engine.training.trainer import ValidationSet, train  # lazy: torch

    options: TrainOptions = options_from_args(TrainOptions, args)
    if not args.scenes and not args.synthetic:
        raise DeepCError("deepc train: give training scenes (SCENE_OR_RUN ...) and/or --synthetic SEEDS")
    if (args.refine_weights or args.set) and not args.refined:
        raise DeepCError("deepc train: --refine-weights and --set only make sense with --refined")
    scene_options = SceneOptions(num_source_views=args.num_source_views, max_image_size=args.max_image_size)
    pipeline_options = PipelineOptions(pipeline="vanilla",
                                       patchmatch=PatchMatchOptions(schedule=args.schedule, seed=0)).validate()
    cache = Path(args.cache)
    default_name = f"{'refined_' if args.refined else ''}{options.loss}_{options.fusion}"
    out = Path(args.out) if args.out else Path("runs/train") / default_name / "weights.pt"
    checkpoint = Path(args.checkpoint) if args.checkpoint else out.with_name(out.stem + ".checkpoint.pt")

    t = time.perf_counter()
    refiner = Refiner(args.refine_weights, refine_options(args.set)) if args.refined else None
    train_runs = _resolve_runs(args.scenes, args.synthetic, cache, scene_options, pipeline_options)
    train_samples = _load(train_runs, refiner)
    validation = []
    for path in args.validation:
        run = _resolve_runs([path], [], cache, scene_options, pipeline_options)
        validation.append(ValidationSet(Path(path).name, _subset(_load(run, refiner), args.validation_max_views)))
    if args.validation_synthetic:
        runs = _resolve_runs([], args.validation_synthetic, cache, scene_options, pipeline_options)
        validation.append(ValidationSet("synthetic_heldout",
                                        _subset(_load(runs, refiner), args.validation_max_views)))
    overlap = {s.scene for s in train_samples} & {s.scene for v in validation for s in v.samples}
    if overlap:
        raise DeepCError(f"scene(s) {', '.join(sorted(overlap))} are both in training and validation")
    labelled = sum(int((s.labels >= 0).sum()) for s in train_samples)
    named = [(v, plural(len(v.samples), "view")) for v in validation]
    _log(f"training data ({'refined' if refiner else 'vanilla'} maps): {plural(len(train_runs), 'run')}, "
         f"{plural(len(train_samples), 'view')}, {labelled:,} labelled pixels; "
         f"validation: {', '.join(f'{v.name} ({n})' for v, n in named) or 'none'} "
         f"({time.perf_counter() - t:.0f} s)")

    progress = _progress_logger(options, checkpoint)
    data_names = sorted({s.scene for s in train_samples})
    init = None
    if args.init:
        from engine.confidence.weights import load_weights  # lazy: torch

        init = load_weights(args.init)
    result = train(train_samples, validation, options, checkpoint, out, progress=progress,
                   data_names=data_names, max_epochs=args.max_epochs, init=init,
                   init_name=str(Path(args.init).resolve()) if args.init else "",
                   inputs=refiner.description() if refiner else None)
    result["validation_sets"] = {v.name: [s.view for s in v.samples] for v in validation}
    write_json(out.with_name(out.stem + ".history.json"), result)
    best = result["best"]
    if args.model_card:
        write_model_card(Path(args.model_card), out, result, train_runs, args)
    print(json.dumps({"weights": str(out), "best_epoch": best["epoch"], "score": best["score"],
                      "epochs_done": result["epochs_done"]}))
    return 0


def write_model_card(path: Path, weights: Path, result: dict, train_runs: list[Path], args: argparse.Namespace) -> None:
    """A Markdown model card for the best weights of a training."""
    from engine.confidence.weights import load_weights  # lazy: torch

    model = load_weights(weights)
    meta = model.meta
    best = result["best"]
    history = result["history"]
    lines = [
        f"# Confidence network weights: `{weights.name}`", "",
        f"- Written: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; best epoch "
        f"{best['epoch']} of {result['epochs_done']} (trained {meta.get('trained')}).",
        f"- Architecture: DeepC U-Net, {model.fusion} fusion, widths {list(model.widths)}, "
        f"{result['parameters']:,} parameters; stored as fp16 ({weights.stat().st_size / 2**20:.1f} MB).",
        f"- Training time: {sum(h['train_seconds'] for h in history) / 60:.1f} min of optimisation + "
        f"{sum(h['validation_seconds'] for h in history) / 60:.1f} min of validation on a shared 2-core CPU"
        + (f"; warm start from `{meta['init']}`" if meta.get("init") else "") + ".",
        f"- Training data ({len(train_runs)} scenes, whole scenes only): "
        + ", ".join(sorted(Path(r).name for r in train_runs)) + ". Engine runs: vanilla PatchMatch, "
        f"schedule {args.schedule}, {args.num_source_views} source views, labels as in Kuhn et al. 2020, §3.2 (2 px).",
        inputs_line(meta.get("inputs")),
        "- Options: " + ", ".join(f"{k}={v}" for k, v in meta.get("options", {}).items()), "",
        "## Validation ROC-AUC ×100 (pooled over labelled pixels) at the selected epoch", "",
        "| set | views | ROC-AUC | inliers |", "|---|---|---|---|",
    ]
    for name, v in best["validation"]["sets"].items():
        lines.append(f"| {name} | {len(v['per_view'])} | {v['auc']:.2f} | {100 * v['inlier_fraction']:.1f}% |")
    lines += ["", "## History", "", "| epoch | loss | " + " | ".join(best["validation"]["sets"]) + " |",
              "|---|---|" + "---|" * len(best["validation"]["sets"])]
    for h in history:
        aucs = " | ".join(f"{v['auc']:.2f}" for v in h["validation"]["sets"].values())
        lines.append(f"| {h['epoch']} | {h['loss']:.4f} | {aucs} |")
    atomic_write_text(path, "\n".join(lines) + "\n")
