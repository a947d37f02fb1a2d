"""The shipped network means something: on a scene it was never trained on, its ROC-AUC beats the counter map's.

sample_scenes/tiny is the hand-made layout of ``engine.synthetic.layout.tiny_scene``, not one of the random scenes
``engine.synthetic.dataset.training_recipe(seed)`` renders for training, and not a scene of the recipe's splits; the
network sees only its vanilla maps. The counter map (source views confirming each pixel) divided by the view's
number of sources is the baseline score: it is one of the network's inputs, so a network that only echoed it would
not beat it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from engine.confidence.weights import DEFAULT_WEIGHTS
from engine.run.folder import read_map, read_metrics
from engine.run.scores import confidence_auc
from engine.scene import SceneOptions, load_scene
from workbench.cli.main import main

REPO = Path(__file__).resolve().parent.parent
TINY = REPO / "sample_scenes" / "tiny"
RECIPE = REPO / "engine" / "confidence" / "recipes" / "deepc_middle.toml"
# Measured on 2026-11-28 (seed 0, this run's settings): network 96.37, counter 93.10 (margin 3.27); on the full
# 160x120 images with the ACMM schedule 97.34 against 94.14 (3.20), with the default schedule 97.53 against 94.30
# (3.23). The test asks for 2 points, two thirds of the measured margin.
MARGIN = 2.0


def test_tiny_is_not_a_training_or_validation_scene():
    recipe = tomllib.loads(RECIPE.read_text())
    named = [s if isinstance(s, str) else s["path"] for split in recipe["split"].values() if isinstance(split, list)
             for s in split]
    assert not [s for s in named if Path(s).name in ("tiny", "small")]
    # the recipe's synthetic scenes are engine.synthetic.dataset's seeds, named synth_NNNNN: tiny is none of them
    assert load_scene(TINY).name == "tiny"


def test_shipped_network_beats_the_counter_on_an_unseen_scene(tmp_path):
    out = tmp_path / "run"
    code = main(["run", str(TINY), "--out", str(out), "--headless", "--pipeline", "fast", "--schedule", "acmm",
                 "--max-image-size", "120", "--no-history", "--set", "confidence.num_threads=1"])
    assert code == 0
    metrics = read_metrics(out)
    assert Path(metrics["options"]["confidence"]["weights"] or DEFAULT_WEIGHTS).name == "deepc_middle.pt"
    scene = load_scene(TINY, SceneOptions.from_dict(metrics["options"]["scene"]))
    names = [v.name for v in scene.views]

    def depth(i):
        return read_map(out, "depth", names[i])

    def network(i):
        return read_map(out, "confidence", names[i])

    def counter(i):
        return read_map(out, "counter", names[i]) / len(scene.views[i].source_views)

    ours = confidence_auc(scene, depth, network)["pooled"]
    baseline = confidence_auc(scene, depth, counter)["pooled"]
    assert ours == metrics["confidence_auc"]  # the run scored the same maps
    assert ours >= baseline + MARGIN, f"network ROC-AUC {ours:.2f}, counter {baseline:.2f}"
