"""Sky filter (Kuhn et al. 2020, §5.5): precision/recall on the synthetic sample scene, connectivity, far plane."""

from __future__ import annotations

import numpy as np
import pytest

from engine.core.errors import OptionsError
from engine.refinement.sky import SkyOptions, far_mask, filter_sky, sky_mask
from engine.scene import load_scene
from tests.conftest import SAMPLES


def test_sky_mask_precision_recall_on_small_scene():
    """GT depth 0 = sky. When the vanilla maps have nothing reliable in the sky (no depth there), the
    mask finds it with high precision; where the vanilla maps are reliable nothing is called sky."""
    scene = load_scene(SAMPLES / "small")
    tp = fp = fn = 0
    for v in scene.views:
        sky = scene.gt_depth(v.index) <= 0
        vanilla = np.where(sky, 0.0, 5.0)  # a vanilla map whose sky is invalid, the rest valid
        mask = sky_mask(scene.image(v.index), vanilla)
        tp += int((mask & sky).sum())
        fp += int((mask & ~sky).sum())
        fn += int((~mask & sky).sum())
        # Everything valid and confident: nothing may be removed.
        assert not sky_mask(scene.image(v.index), np.full(sky.shape, 5.0), np.ones(sky.shape)).any()
    precision, recall = tp / (tp + fp), tp / (tp + fn)
    assert tp + fn > 0.1 * len(scene.views) * 320 * 240  # the scene does have sky
    assert precision > 0.99 and recall > 0.8, (precision, recall)


def test_sky_mask_needs_top_border_low_texture_and_unreliable():
    rng = np.random.default_rng(0)
    rgb = np.clip(0.4 + 0.2 * rng.standard_normal((40, 50, 3)), 0, 1)  # textured background
    rgb[:10] = [0.6, 0.7, 0.9]  # flat blue band at the top: sky
    rgb[25:35, 10:20] = [0.9, 0.9, 0.9]  # flat bright blob not touching the top: not sky
    depth = np.zeros((40, 50))  # nothing reliable anywhere
    mask = sky_mask(rgb, depth)
    assert mask[:7].all() and not mask[25:35, 10:20].any() and mask[10:].sum() == 0
    conf = np.ones((40, 50))
    conf[:5] = 0.0
    mask = sky_mask(rgb, np.full((40, 50), 3.0), conf)  # reliable below row 5
    assert mask[:5].all() and not mask[5:].any()


def test_far_plane_and_filter():
    depth = np.array([[1.0, 14.9, 15.0, 16.0]], np.float32)
    far = far_mask(depth, z99=10.0, far_factor=1.5)
    assert far.tolist() == [[False, False, True, True]]
    normal = np.ones((1, 4, 3), np.float32)
    sky = np.array([[True, False, False, False]])
    d, n = filter_sky(depth, normal, sky, far)
    assert d.tolist() == [[0.0, np.float32(14.9), 0.0, 0.0]] and n[0, 1].tolist() == [1, 1, 1] and not n[0, 0].any()


def test_sky_options_validate():
    with pytest.raises(OptionsError, match="texture_window"):
        SkyOptions(texture_window=4).validate()
