"""Model cards of recipe trainings: what the weights saw, with every scene's citation, and how they scored."""

from __future__ import annotations

import datetime
import re
from pathlib import Path

from engine.io.atomic import atomic_write_text
from engine.training.recipe import Recipe, SceneEntry

# where a scene README's citation paragraph stops (the licence text that follows it)
_CITATION_END = re.compile(r"\s(Middlebury distributes|The repository is|No licence|Permission is hereby)")


def scene_citation(entry: SceneEntry) -> str:
    """The citation of a recipe scene: the 'Citation' paragraph of its README.txt (first sentences only)."""
    if entry.synthetic:
        return f"synthetic scene rendered by engine.synthetic.dataset (seed {entry.seed}); no citation"
    readme = entry.path / "README.txt" if entry.path else None
    if readme is None or not readme.is_file():
        return "no README.txt: citation unknown"
    lines = readme.read_text(errors="replace").splitlines()
    for i, line in enumerate(lines):
        if line.strip().lower().startswith("citation"):
            paragraph = []
            for body in lines[i + 1:]:
                if not body.startswith(" ") or not body.strip():
                    break
                paragraph.append(body.strip())
            text = " ".join(paragraph)
            return _CITATION_END.split(text, maxsplit=1)[0].strip() or "citation paragraph empty"
    return "README.txt has no citation paragraph"


def inputs_line(inputs: dict | None) -> str:
    """The model card's line on what the network's inputs are (``meta["inputs"]`` of a weights file)."""
    if not inputs or inputs.get("maps") != "refined":
        return "- Network inputs: vanilla PatchMatch maps (network 1: `confidence.weights` of --pipeline fast, full)."
    refinement = inputs["refinement"]
    return ("- Network inputs: refined maps (network 2, `confidence.refined_weights` of --pipeline full): every run "
            f"refined as the full pipeline does, guided by network 1 `{Path(inputs['refine_weights']).name}` "
            f"(sha256 {inputs['refine_weights_sha256'][:12]}; {refinement['solver']} solver, {refinement['scales']} "
            "scales), counter maps recomputed on the refined maps; labels compare the refined depth with GT depth.")


def write_recipe_model_card(path: Path, weights: Path, result: dict, recipe: Recipe) -> None:
    """A Markdown card: recipe, split with citations, options, training time, validation history."""
    from engine.confidence.weights import load_weights  # lazy: torch

    model = load_weights(weights)
    meta, best, history = model.meta, result["best"], result["history"]
    train_min = sum(h["train_seconds"] for h in history) / 60
    val_min = sum(h["validation_seconds"] for h in history) / 60
    lines = [
        f"# Confidence network weights: `{weights.name}` (recipe `{recipe.name}`)", "",
        f"- Made by `deepc train --recipe {recipe.path}` on "
        f"{datetime.datetime.now(datetime.UTC).date().isoformat()}; best epoch {best['epoch']} of "
        f"{result['epochs_done']}, selected by the mean validation ROC-AUC.",
        f"- Architecture: DeepC U-Net, {model.fusion} fusion, widths {list(model.widths)}, "
        f"{result['parameters']:,} parameters; stored as fp16 ({weights.stat().st_size / 2**20:.1f} MB).",
        f"- Training time: {train_min:.1f} min of optimisation + {val_min:.1f} min of validation on "
        f"{meta.get('device', 'cpu')} (engine runs of the scenes not included; they are cached).",
        "- Options: " + ", ".join(f"{k}={v}" for k, v in meta.get("options", {}).items()),
        f"- Sampling: {100 * recipe.real_share:.0f} % of the training crops from real views, the rest from "
        "synthetic ones, uniformly over the views within each group.",
        inputs_line(meta.get("inputs")), "",
        "## Scenes (split chosen before training)", "",
        "| split | scene | engine run | citation |", "|---|---|---|---|",
    ]
    for split in ("train", "validation", "test"):
        for e in recipe.scenes(split):
            run = ", ".join(f"{k} {v}" for k, v in e.engine.items()) or "defaults"
            lines.append(f"| {split} | {e.name} | {run} | {scene_citation(e)} |")
    sets = list(best["validation"]["sets"])
    lines += ["", "## Validation ROC-AUC ×100 (network alone, pooled over each scene's labelled pixels)", "",
              "| epoch | loss | " + " | ".join(sets) + " | mean |", "|---|---|" + "---|" * (len(sets) + 1)]
    for h in history:
        aucs = " | ".join(f"{h['validation']['sets'][k]['auc']:.2f}" for k in sets)
        mark = " (selected)" if h["epoch"] == best["epoch"] else ""
        lines.append(f"| {h['epoch']}{mark} | {h['loss']:.4f} | {aucs} | {h['validation']['score']:.2f} |")
    lines += ["", "## Recipe", "", "```toml", recipe.text.rstrip(), "```"]
    atomic_write_text(path, "\n".join(lines) + "\n")
