"""Randomised synthetic scenes for training the confidence network.

Each seed gives one whole scene (never shared views between scenes), so splits by seed are splits by
scene. The knobs vary more than :class:`RandomSceneKnobs` alone: image size and view count are drawn
per seed too, so the network sees several pixel scales of the same kinds of texture.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.synthetic.export import write_scene
from engine.synthetic.layout import random_scene

#: (width, height) choices for training scenes; fountain_p11 at 768 px has 1.5-2.4x finer texture than these.
SIZES = ((256, 192), (320, 240), (384, 256), (384, 288))

#: Seeds from here on draw "hard" scenes: large, often weakly textured objects (shading only), where
#: PatchMatch converges to a wrong surface that the views agree on (high counter, smooth normals). The
#: default knobs make such objects rare (weak texture 15 %, radius <= 0.6 m), and the network learnt to
#: trust them (session 3: held-out synth_01003, a 0.59 m weak sphere, AUC 80).
HARD_SEED_START = 2000
HARD_KNOBS = {"weak_prob": 0.5, "n_spheres": (1, 3), "sphere_radius": (0.45, 0.95), "n_boxes": (1, 3)}


def training_scene_name(seed: int) -> str:
    """Folder name of the scene drawn from ``seed``."""
    return f"synth_{seed:05d}"


def training_recipe(seed: int):
    """The :class:`SceneRecipe` of training scene ``seed`` (deterministic)."""
    rng = np.random.Generator(np.random.PCG64(10_000 + seed))
    width, height = SIZES[int(rng.integers(len(SIZES)))]
    n_views = int(rng.integers(5, 8))
    knobs = HARD_KNOBS if seed >= HARD_SEED_START else {}
    recipe = random_scene(seed, width=width, height=height, n_views=(n_views, n_views), **knobs)
    recipe.name = training_scene_name(seed)
    return recipe


def write_training_scenes(out_root: str | Path, seeds: list[int], overwrite: bool = False) -> list[Path]:
    """Render the scenes of ``seeds`` into ``out_root/<name>`` (each written atomically); existing complete
    scenes are kept unless ``overwrite``. Returns the scene folders in the order of ``seeds``."""
    out_root = Path(out_root)
    paths = []
    for seed in seeds:
        path = out_root / training_scene_name(seed)
        if overwrite or not (path / "README.txt").is_file():
            write_scene(training_recipe(seed), path, binary_model=True,
                        command=f"engine.synthetic.dataset.write_training_scenes(..., [{seed}])")
        paths.append(path)
    return paths
