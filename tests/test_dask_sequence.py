"""The long street sequences of the Dask scaling benchmark (engine/synthetic/sequence.py): views one metre apart
whose source views are their neighbours in the sequence, so the work per view does not grow with its length."""

from __future__ import annotations

import numpy as np
import pytest

from engine.scene import load_scene
from engine.synthetic import write_scene
from engine.synthetic.sequence import street_scene


def test_street_recipe_is_a_sequence_one_metre_apart():
    recipe = street_scene(30, 64, 48)
    centers = np.array([c.center for c in recipe.cameras])
    steps = np.linalg.norm(np.diff(centers, axis=0), axis=1)
    assert len(recipe.cameras) == 30 and np.all(np.abs(steps - 1.0) < 0.1)
    assert street_scene(30, 64, 48).cameras[7].t.tolist() == recipe.cameras[7].t.tolist()  # seeded
    with pytest.raises(ValueError):
        street_scene(1)


@pytest.mark.slow
def test_street_scene_loads_with_neighbouring_source_views(tmp_path):
    write_scene(street_scene(10, 96, 72), tmp_path / "street")
    scene = load_scene(tmp_path / "street")
    assert len(scene.views) == 10 and scene.has_gt_depth
    for v in scene.views:
        assert v.source_views and max(abs(j - v.index) for j in v.source_views) <= 6
