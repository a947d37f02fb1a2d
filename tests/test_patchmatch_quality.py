"""PatchMatch depth quality on sample_scenes/tiny with DEFAULT options, pooled over the 5 views.

Issue target: within_1pct >= 90 % and valid_fraction >= 95 %. Measured with the current defaults
(the 5x5 fine window within 5 px of depth edges and of creases sharper than 20 degrees, the latter only where
the fine window keeps 10 % of the standard window's variance, a constant good-cost threshold (alpha 0),
detail_restorer_reference='random', eps_schedule='global', min_improvement 0.003): within_1pct 90.08 %
(seeds 0-2: 90.08 / 90.08 / 90.09), within_5pct 95.4 %, valid 100 %. Without the crease band it is 89.5 %,
with the 11x11 window alone (the paper's) about 80 %: that window straddles both surfaces along occlusion edges
and creases on 160x120 images. What is left: background pixels beside the objects that one or two of the
four source views see and the strips of the outer views that no source view sees (2.6 %, never right); see
the engineering notes and benchmarks/results/ncc_sharpness_fine_crease_angle.json. The margin over the target is small
(0.08 points): a change that costs tiny precision shows here first.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.evaluation import EvaluationOptions
from engine.evaluation.depth import depth_metrics
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, fuse, views_from_scene
from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.run.pipeline import PipelineOptions, evaluate_cloud, patchmatch_views
from engine.scene import load_scene

TINY = Path(__file__).resolve().parent.parent / "sample_scenes" / "tiny"


@pytest.fixture(scope="module")
def tiny_maps():
    scene = load_scene(TINY)
    return scene, run_patchmatch(patchmatch_views(scene), PatchMatchOptions())


def _pooled(scene, maps) -> dict[str, float]:
    """Depth metrics pooled over the views (engine.evaluation.depth.depth_metrics on all pixels at once)."""
    return depth_metrics(np.concatenate([m.depth.ravel() for m in maps]),
                         np.concatenate([scene.gt_depth(i).ravel() for i in range(len(maps))]))


@pytest.fixture(scope="module")
def pooled(tiny_maps) -> dict[str, float]:
    return _pooled(*tiny_maps)


def test_tiny_issue_target(pooled) -> None:
    # measured 90.08 / 95.4 / 100 (seeds 0-2: 90.08-90.09); 89.5 without the crease band
    # (fine_crease_angle=0), 80 / 92 with the 11 px window alone, 70 with the paper's literal restorer
    assert pooled["valid_fraction"] >= 95.0, pooled
    assert pooled["within_1pct"] >= 90.0, pooled
    assert pooled["within_5pct"] >= 95.0, pooled


def test_fine_window_sharpens_occlusion_edges_and_creases(tiny_maps) -> None:
    """Two levels, ACMM schedule (a short run), the same options but the window: the default (the 5x5 fine
    window within 5 px of the depth discontinuities and creases of each pass's starting map, measured 90.2 %)
    and the fine window wherever its texture test passes (fine_edge_radius=0, measured 90.2 %) against the
    11 px window alone (fine_window=0, measured 80.8 %). The large window's foreground fattening along tiny's
    occlusion edges is what the fine window removes; the band keeps the 11 px window's precision inside
    surfaces away from edges (benchmarks/results/ncc_sharpness_fine_window_edges.json). Without the crease band
    (fine_crease_angle=0) it is 89.8 %: the 11 px window straddles the planes where walls meet the floor."""
    scene = tiny_maps[0]
    views = patchmatch_views(scene)
    quick = dict(levels=2, schedule="acmm")

    def within_1pct(**extra) -> float:
        return _pooled(scene, run_patchmatch(views, PatchMatchOptions(**quick, **extra)))["within_1pct"]

    window11 = within_1pct(fine_window=0)
    default = within_1pct()
    for fine in (default, within_1pct(fine_edge_radius=0)):
        assert fine >= 89.0 and fine >= window11 + 5.0, (fine, window11)
    no_crease = within_1pct(fine_crease_angle=0.0)
    assert default >= no_crease + 0.2, (default, no_crease)


def test_default_fusion_keeps_the_maps_density(tiny_maps) -> None:
    """The default preset (every pixel of a kept cluster its own point) against the median-point presets
    on the same maps: `dense` (half-pixel clusters, 2 pixels) and the paper's `deepc` (1 px, 3 pixels).
    Measured here: 76,415 points against 21,439 (dense) and 9,946 (deepc); F1 at 2 cm 83.3 against 76.0
    and 53.8 (completeness 72.6, 62.2, 37.0); accuracy 97.7, 97.7, 98.5. A user would see a sparser,
    worse-scoring cloud if the default slid back."""
    scene, maps = tiny_maps
    assert PipelineOptions().fusion == FUSION_PRESETS[DEFAULT_PRESET]
    views = views_from_scene(scene, [m.depth for m in maps], [m.normal for m in maps])
    options = EvaluationOptions(tolerances=(0.02,))
    clouds = {name: fuse(views, FUSION_PRESETS[name]) for name in (DEFAULT_PRESET, "dense", "deepc")}
    scores = {name: evaluate_cloud(scene, cloud, options) for name, cloud in clouds.items()}
    default, dense, paper = (clouds[n] for n in (DEFAULT_PRESET, "dense", "deepc"))
    r_default, r_dense, r_paper = (scores[n] for n in (DEFAULT_PRESET, "dense", "deepc"))
    assert len(dense) > 1.6 * len(paper), (len(dense), len(paper))
    assert len(default) > 3 * len(dense), (len(default), len(dense))
    assert r_dense.f1[0] > r_paper.f1[0] + 10.0, (r_dense.f1, r_paper.f1)
    assert r_default.f1[0] > r_dense.f1[0] + 4.0, (r_default.f1, r_dense.f1)
    assert r_default.completeness[0] > r_dense.completeness[0] + 5.0, (r_default.completeness, r_dense.completeness)
    assert r_default.accuracy[0] > min(r_dense.accuracy[0], r_paper.accuracy[0]) - 2.0, (r_default.accuracy,)
