"""Synthetic multi-view scenes with exact ground truth (ray-cast primitives, solid textures).

Typical use::

    from engine.synthetic import tiny_scene, render_scene, write_scene
    write_scene(render_scene(tiny_scene()), "sample_scenes/tiny", binary_model=False)
"""

from engine.synthetic.export import write_scene
from engine.synthetic.layout import RandomSceneKnobs, random_scene, small_scene, tiny_scene
from engine.synthetic.render import render_scene
from engine.synthetic.scene import RenderSettings, SceneData, SceneRecipe, SparseModel, SparseSettings

__all__ = ["RandomSceneKnobs", "RenderSettings", "SceneRecipe", "SceneData", "SparseModel", "SparseSettings",
           "random_scene", "render_scene", "small_scene", "tiny_scene", "write_scene"]
