"""The flags of ``deepc train`` (``workbench/cli/train.py`` runs the command).

Declared apart from the command so that building the ``deepc`` parser does not import the training
code and the engine pipeline behind it.
"""

from __future__ import annotations

import argparse

from engine.confidence.options import TrainOptions
from engine.training.recipe import parse_seeds as seeds_of
from workbench.flags.options import add_options_flags

#: ``--set`` stages of ``deepc train --refined`` (those that determine the refined maps)
REFINE_SECTIONS = ("refinement", "counter", "confidence")


def parse_seeds(text: str) -> list[int]:
    """'0-59' or '1,2,5-9' -> list of ints (an argparse type)."""
    try:
        return seeds_of(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds must look like 0-59 or 1,2,5-9, got {text!r}") from None


def add_train_arguments(train: argparse.ArgumentParser) -> None:
    """The arguments of ``deepc train`` on its sub-parser."""
    train.add_argument("scenes", nargs="*", metavar="SCENE_OR_RUN",
                       help="training scenes with GT depth maps, or finished run folders of such scenes")
    train.add_argument("--recipe", default=None, metavar="FILE.toml",
                       help="train as the recipe says (scenes, split, engine runs, options; see "
                            "engine/confidence/recipes/); flags given explicitly override its [training]")
    train.add_argument("--data", default=None, metavar="DIR",
                       help="with --recipe: the folder its scene paths are relative to (default: its [data] root)")
    train.add_argument("--synthetic", type=parse_seeds, default=[], metavar="SEEDS",
                       help="also train on these randomised synthetic scenes, e.g. 0-59")
    train.add_argument("--validation", nargs="*", default=[], metavar="SCENE_OR_RUN",
                       help="held-out scenes or runs scored every epoch (each a separate ROC-AUC)")
    train.add_argument("--validation-synthetic", type=parse_seeds, default=[], metavar="SEEDS",
                       help="held-out synthetic scenes, scored together, e.g. 1000-1003")
    train.add_argument("--cache", default="runs/train_cache", metavar="DIR",
                       help="cache of rendered scenes (DIR/scenes) and engine runs (DIR/runs)")
    train.add_argument("--out", default=None, metavar="WEIGHTS.pt",
                       help="best weights (default: runs/train/<loss>_<fusion>/weights.pt)")
    train.add_argument("--checkpoint", default=None, metavar="FILE",
                       help="resumable state, written every epoch (default: next to --out); an existing "
                            "checkpoint is resumed")
    train.add_argument("--max-epochs", type=int, default=None, metavar="N",
                       help="stop after this many epochs in total (resume later to go on)")
    train.add_argument("--init", default=None, metavar="WEIGHTS.pt",
                       help="start from these weights (warm start) instead of a random initialisation")
    train.add_argument("--validation-max-views", type=int, default=0, metavar="N",
                       help="score at most N evenly spaced views of each validation set per epoch (0 = all)")
    train.add_argument("--model-card", default=None, metavar="FILE.md",
                       help="also write a model card (data, options, validation ROC-AUC per scene, date)")
    train.add_argument("--refined", action="store_true",
                       help="train the second network of --pipeline full (confidence.refined_weights): every "
                            "training and validation run is first refined as the full pipeline does (confidence "
                            "of --refine-weights, refinement, counter maps of the refined maps; cached in "
                            "RUN/refined/ and reused while weights, options and maps match) and the network "
                            "learns on the refined maps")
    train.add_argument("--refine-weights", default=None, metavar="WEIGHTS.pt",
                       help="with --refined: network-1 weights whose confidence guides the refinement "
                            "(default: the shipped engine/confidence/weights/deepc_middle.pt)")
    train.add_argument("--set", action="append", default=[], metavar="STAGE.NAME=VALUE",
                       help="with --refined: options of that refinement as for deepc run --pipeline full, stages "
                            f"{', '.join(REFINE_SECTIONS)}, e.g. --set refinement.lambda_reg=5")
    engine_group = train.add_argument_group("engine runs on training scenes")
    engine_group.add_argument("--num-source-views", type=int, default=4, metavar="N")
    engine_group.add_argument("--max-image-size", type=int, default=0, metavar="PX")
    engine_group.add_argument("--schedule", choices=("paper", "acmm"), default="acmm")
    add_options_flags(train.add_argument_group("training"), TrainOptions)
