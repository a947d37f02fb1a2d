"""Refinement (Rossi et al. 2020): energy, graph, plane conversions, numba kernels against plain references,
recovery of a piece-wise planar scene, and the behaviour on bad input."""

from __future__ import annotations

import math
import os
import signal

import numpy as np
import pytest
import torch

from engine.core.blocks import MIN_ROWS, RowPacer
from engine.core.errors import DeepCError, OptionsError
from engine.core.interrupt import deferred_interrupts
from engine.refinement import (
    NoDataError,
    RefinementOptions,
    build_problem,
    energy_terms,
    normal_to_u,
    refine_depth,
    similarity_graph,
    u_to_normal,
)
from engine.refinement.adam import TorchEnergy
from engine.refinement.primal_dual import (
    dual_step,
    preconditioners,
    primal_step,
)
from support.refinement_reference import (
    dual_step_reference,
    energy_terms_reference,
    primal_step_reference,
    similarity_graph_reference,
)


def _graph_by_loops(gray, window, patch, sigma_int, sigma_spa, degree):
    """Per pixel {j: w_ij} straight from the definition of Rossi et al. 2020."""
    h, w = gray.shape
    rw, rp = window // 2, patch // 2

    def px(r, c):
        return gray[min(max(r, 0), h - 1), min(max(c, 0), w - 1)]

    out = []
    for r in range(h):
        for c in range(w):
            cand = []
            for dy in range(-rw, rw + 1):
                for dx in range(-rw, rw + 1):
                    if (dy, dx) == (0, 0) or not (0 <= r + dy < h and 0 <= c + dx < w):
                        continue
                    pd = sum((px(r + oy, c + ox) - px(r + dy + oy, c + dx + ox)) ** 2
                             for oy in range(-rp, rp + 1) for ox in range(-rp, rp + 1))
                    wh = math.exp(-pd / (2 * sigma_int ** 2) - (dy * dy + dx * dx) / (2 * sigma_spa ** 2))
                    cand.append((wh, (r + dy) * w + c + dx))
            cand.sort(reverse=True)
            kept = cand[:degree]
            total = sum(x for x, _ in kept)
            out.append({j: x / total for x, j in kept})
    return out


def _as_dicts(graph):
    return [{int(j): float(x) for j, x in zip(nb, ws, strict=True) if x > 0}
            for nb, ws in zip(graph.neighbors, graph.weights, strict=True)]


def test_graph_matches_definition():
    rng = np.random.default_rng(1)
    gray = rng.random((7, 9))
    args = (5, 3, 0.2, 1.5, 6)
    want = _graph_by_loops(gray, *args)
    for graph in (similarity_graph(gray, *args), similarity_graph_reference(gray, *args)):
        got = _as_dicts(graph)
        for g, wnt in zip(got, want, strict=True):
            assert g.keys() == wnt.keys()
            assert all(abs(g[j] - wnt[j]) < 1e-6 for j in g)
        assert np.allclose(graph.weights.sum(1), 1.0, atol=1e-5)
    # Empty slots point to the pixel itself with weight 0 (a corner pixel of a 2x2 image has 3 candidates).
    small = similarity_graph(rng.random((2, 2)), 3, 3, 0.07, 3.0, 5)
    assert np.all(small.neighbors[:, 3:] == np.arange(4)[:, None]) and np.all(small.weights[:, 3:] == 0)


class StopAfterFirstBlock(RowPacer):
    """The real row pacer, with a SIGTERM sent to this process when the first block returns (what Ctrl-C during
    a long graph build does); records the blocks that ran."""

    def __init__(self):
        super().__init__()
        self.done: list[tuple[int, int]] = []

    def run(self, kind: str, height: int, width: int, call) -> None:
        def then_stop(start: int, stop: int) -> None:
            call(start, stop)
            self.done.append((start, stop))
            if len(self.done) == 1:
                os.kill(os.getpid(), signal.SIGTERM)

        super().run(kind, height, width, then_stop)


def test_graph_is_the_same_for_any_row_blocks_and_a_stop_request_ends_it_between_blocks():
    """The similarity graph built in one call, in uneven fixed blocks and in the paced blocks of a real run is the
    same bit for bit; a stop request (SIGTERM inside deferred_interrupts) during a block ends the build when that
    block returns, before the next one starts."""
    from test_patchmatch_kernels import FixedBlocks

    gray = np.random.default_rng(4).random((31, 23))
    args = (5, 3, 0.2, 1.5, 6)
    whole = similarity_graph(gray, *args, pacer=None)
    assert (whole.weights.sum(1) > 0).all()  # every pixel has neighbours: the blocks all wrote
    for pacer in (FixedBlocks(1, 2, 9, 29, 30), FixedBlocks(16), RowPacer(target_s=1e-6)):
        graph = similarity_graph(gray, *args, pacer=pacer)
        assert graph.neighbors.tobytes() == whole.neighbors.tobytes()
        assert graph.weights.tobytes() == whole.weights.tobytes()
    stopper = StopAfterFirstBlock()
    with pytest.raises(KeyboardInterrupt), deferred_interrupts():
        similarity_graph(gray, *args, pacer=stopper)
    assert stopper.done == [(0, MIN_ROWS)]  # the first block, and no other after the request


def _energy_by_loops(d, u, dbar, fid, graph, lam_d, lam, gamma):
    n = len(d)
    w_img = graph.width
    data = sum(fid[i] * abs(d[i] - dbar[i]) for i in range(n))
    plane = tv = 0.0
    for i in range(n):
        xi, yi = i % w_img, i // w_img
        sq = 0.0
        for j, wij in zip(graph.neighbors[i], graph.weights[i], strict=True):
            xj, yj = j % w_img, j // w_img
            sq += (wij * (d[i] - d[j] - u[i, 0] * (xi - xj) - u[i, 1] * (yi - yj))) ** 2
            tv += wij * math.hypot(u[i, 0] - u[j, 0], u[i, 1] - u[j, 1])
        plane += math.sqrt(sq)
    return (lam_d * data + lam * (plane + gamma * tv)) / n


def test_energy_matches_plain_loops():
    rng = np.random.default_rng(2)
    h, w = 6, 7
    opts = RefinementOptions(window=5, degree=8)
    depth = rng.uniform(1, 3, (h, w))
    depth[0, :3] = 0  # missing input: no fidelity
    depth[2, 2] = 10  # outside the range: no fidelity
    conf = rng.random((h, w))
    problem = build_problem(rng.random((h, w)), depth, conf, (0.5, 5.0), opts)
    assert problem.fidelity[0] == 0 and problem.fidelity[2 * w + 2] == 0
    d = rng.uniform(0.2, 2, h * w)
    u = rng.normal(0, 0.05, (h * w, 2))
    want = _energy_by_loops(d, u, problem.data, problem.fidelity, problem.graph, 1.0, 7.5, 5.5)
    assert energy_terms(problem, d, u)["total"] == pytest.approx(want, rel=1e-6)
    assert energy_terms_reference(problem, d, u)["total"] == pytest.approx(want, rel=1e-6)
    torch_e = TorchEnergy(problem, torch.float64)(torch.tensor(d), torch.tensor(u)).item()
    assert torch_e == pytest.approx(want, rel=1e-6)


def test_u_normal_round_trip_and_plane_prediction():
    rng = np.random.default_rng(3)
    h, w = 8, 10
    K = np.array([[50.0, 0, 4.5], [0, 55.0, 3.5], [0, 0, 1]])
    n = rng.normal(size=(h, w, 3))
    n[..., 2] = -np.abs(n[..., 2]) - 0.5  # facing the camera (z towards the scene)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    z = rng.uniform(1, 4, (h, w))
    u = normal_to_u(n, z, K)
    assert np.allclose(u_to_normal(u, 1 / z, K), n, atol=1e-9)
    assert np.allclose(u_to_normal(np.zeros((h, w, 2)), 1 / z, K), [0, 0, -1])
    # One plane n·X = rho: the u of any pixel predicts the inverse depth of every other pixel exactly.
    normal = np.array([0.3, -0.2, -0.9]) / np.linalg.norm([0.3, -0.2, -0.9])
    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)
    zp = -2.0 / (rays @ normal)
    up = normal_to_u(np.broadcast_to(normal, (h, w, 3)), zp, K)
    pred = 1 / zp[2, 3] + up[2, 3, 0] * (cols - 3) + up[2, 3, 1] * (rows - 2)
    assert np.allclose(pred, 1 / zp, rtol=1e-10)


def _kernel_inputs(seed, h=9, w=11):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(1, 3, (h, w))
    problem = build_problem(rng.random((h, w)), depth, rng.random((h, w)), (0.5, 5.0), RefinementOptions())
    n, k = problem.graph.neighbors.shape
    state = dict(d=rng.uniform(0.3, 1.5, n).astype(np.float32), u=rng.normal(0, 0.05, (n, 2)).astype(np.float32),
                 d_bar=rng.uniform(0.3, 1.5, n).astype(np.float32),
                 u_bar=rng.normal(0, 0.05, (n, 2)).astype(np.float32),
                 p=rng.normal(0, 0.3, (n, k)).astype(np.float32),
                 q=rng.normal(0, 0.5, (n, k, 2)).astype(np.float32))
    return problem, preconditioners(problem), state


def test_dual_kernel_matches_numpy():
    problem, pre, st = _kernel_inputs(4)
    g = problem.graph
    a = {k: v.copy() for k, v in st.items()}
    b = {k: v.astype(np.float64) for k, v in st.items()}
    dual_step(a["d_bar"], a["u_bar"], g.neighbors, g.weights, pre["offsets"], pre["sigma_p"], np.float32(0.7),
               np.float32(5.5), a["p"], a["q"])
    dual_step_reference(b["d_bar"], b["u_bar"], g.neighbors, g.weights.astype(np.float64), pre["offsets"],
                        pre["sigma_p"].astype(np.float64), 0.7, 5.5, b["p"], b["q"])
    assert np.allclose(a["p"], b["p"], atol=1e-5) and np.allclose(a["q"], b["q"], atol=1e-5)
    assert np.linalg.norm(a["p"], axis=1).max() <= 1 + 1e-5


def test_primal_kernel_matches_numpy():
    problem, pre, st = _kernel_inputs(5)
    g = problem.graph
    shrink = (0.4 * problem.fidelity).astype(np.float32)
    a = {k: v.copy() for k, v in st.items()}
    b = {k: v.astype(np.float64) for k, v in st.items()}
    args = (np.float32(problem.d_min), np.float32(problem.d_max), np.float32(5.5))
    primal_step(a["d"], a["u"], a["d_bar"], a["u_bar"], a["p"], a["q"], g.weights, pre["offsets"], pre["in_ptr"],
                 pre["in_src"], pre["in_slot"], pre["tau_d"], pre["tau_u"], problem.data, shrink, *args)
    primal_step_reference(b["d"], b["u"], b["d_bar"], b["u_bar"], b["p"], b["q"], g.neighbors,
                          g.weights.astype(np.float64), pre["offsets"], pre["tau_d"].astype(np.float64),
                          pre["tau_u"].astype(np.float64), problem.data.astype(np.float64),
                          shrink.astype(np.float64), problem.d_min, problem.d_max, 5.5)
    for key in ("d", "u", "d_bar", "u_bar"):
        assert np.allclose(a[key], b[key], atol=1e-5), key


def planar_scene(h=48, w=64, seed=0):
    """Two slanted planes with a textured boundary; noisy depth, holes, low-confidence outliers."""
    rng = np.random.default_rng(seed)
    K = np.array([[60.0, 0, (w - 1) / 2], [0, 60.0, (h - 1) / 2], [0, 0, 1]])
    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    left = cols < 0.55 * w
    d_true = np.where(left, 0.5 + 0.003 * (cols - w / 2) + 0.001 * rows, 0.3 + 0.0015 * rows)
    gray = np.clip(np.where(left, 0.3, 0.7) + 0.03 * rng.standard_normal((h, w)), 0, 1)
    z_true = 1 / d_true
    depth = z_true * (1 + 0.01 * rng.standard_normal((h, w)))
    conf = np.full((h, w), 0.9)
    outliers = rng.random((h, w)) < 0.08
    depth[outliers] = z_true[outliers] * rng.uniform(0.6, 1.6, outliers.sum())
    conf[outliers] = 0.02
    holes = np.zeros((h, w), bool)
    holes[8:16, 6:20] = True
    holes[30:36, 45:60] = True
    depth[holes] = 0
    conf[holes] = 0
    return dict(K=K, gray=gray, depth=depth, conf=conf, z_true=z_true, d_true=d_true, left=left,
                outliers=outliers, holes=holes, range=(1.0, 5.0))


def _true_normals(sc):
    K = sc["K"]
    h, w = sc["depth"].shape
    u = np.stack([np.where(sc["left"], 0.003, 0.0), np.where(sc["left"], 0.001, 0.0015)], -1)
    return u_to_normal(u, sc["d_true"], K)


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1, 1)))


def test_refinement_recovers_planes():
    from engine.core.camera import Camera
    from support.gt_normals import depth_normals

    sc = planar_scene()
    res = refine_depth(sc["gray"], sc["depth"], sc["conf"], sc["K"], sc["range"], None, RefinementOptions())
    rel_in = np.abs(sc["depth"] - sc["z_true"]) / sc["z_true"]
    rel_out = np.abs(res.depth - sc["z_true"]) / sc["z_true"]
    assert np.all(res.depth > 0)  # holes filled
    assert np.median(rel_out[sc["holes"]]) < 0.01  # ... with the planes' depths
    assert np.median(rel_out[sc["outliers"]]) < 0.01 < np.median(rel_in[sc["outliers"]])
    assert np.median(rel_out) < 0.5 * np.median(rel_in[~sc["holes"]])
    # Normals: closer to the truth than normals differentiated from the noisy input.
    n_true = _true_normals(sc)
    cam = Camera.from_params(64, 48, sc["K"][0, 0], sc["K"][1, 1], sc["K"][0, 2] + 0.5, sc["K"][1, 2] + 0.5)
    n_in = depth_normals(cam, sc["depth"], max_relative_jump=0.2)
    has = n_in.any(-1)
    boundary = np.abs(np.arange(64)[None, :] - 0.55 * 64) < 3
    inner = has & ~boundary
    assert np.median(_angle_deg(res.normal, n_true)[inner]) < 0.25 * np.median(_angle_deg(n_in, n_true)[inner])
    assert np.all(np.sum(res.normal * cam.pixel_rays(), -1) < 0)  # facing the camera
    assert res.iterations == list(RefinementOptions().fast_iters) and len(res.energy) == 4


def test_fast_solver_within_one_percent_of_adam():
    sc = planar_scene(20, 28, seed=1)
    sc["K"][:2] *= 0.4
    base = RefinementOptions(scales=2, iters=(900, 300), lr=(1e-2, 1e-3), lr_slots=(3, 2), fast_iters=(600, 300))
    adam = refine_depth(sc["gray"], sc["depth"], sc["conf"], sc["K"], sc["range"], None, base.replace(solver="adam"))
    fast = refine_depth(sc["gray"], sc["depth"], sc["conf"], sc["K"], sc["range"], None, base)
    assert fast.energy[-1] <= 1.01 * adam.energy[-1]
    assert np.median(np.abs(fast.depth - adam.depth) / adam.depth) < 0.005


@pytest.mark.parametrize("case", ["depth_size", "conf_size", "normal_size", "range", "conf_values", "K"])
def test_bad_input_raises_clear_error(case):
    sc = planar_scene(12, 16)
    args = dict(gray=sc["gray"], depth=sc["depth"], confidence=sc["conf"], K_idx=sc["K"],
                depth_range=sc["range"], normal=None)
    bad = {"depth_size": ("depth", np.ones((12, 15))), "conf_size": ("confidence", np.ones((11, 16))),
           "normal_size": ("normal", np.ones((12, 16, 2))), "range": ("depth_range", (3.0, 1.0)),
           "conf_values": ("confidence", sc["conf"] * 3), "K": ("K_idx", np.eye(2))}[case]
    args[bad[0]] = bad[1]
    with pytest.raises(DeepCError, match="refinement"):
        refine_depth(**args)


def test_no_data_views_raise_no_data_error():
    sc = planar_scene(12, 16)
    with pytest.raises(NoDataError, match="zero confidence"):
        refine_depth(sc["gray"], sc["depth"], np.zeros((12, 16)), sc["K"], sc["range"])
    with pytest.raises(NoDataError, match="no pixel has a depth"):
        refine_depth(sc["gray"], np.zeros((12, 16)), sc["conf"], sc["K"], sc["range"])
    with pytest.raises(NoDataError, match="no pixel has a depth"):  # every depth outside the range
        refine_depth(sc["gray"], np.full((12, 16), 50.0), sc["conf"], sc["K"], sc["range"])


def test_output_stays_in_range_and_binarised_confidence():
    sc = planar_scene(16, 20)
    res = refine_depth(sc["gray"], sc["depth"], sc["conf"], sc["K"], (1.9, 3.0),
                       options=RefinementOptions(scales=2, fast_iters=(50, 50), iters=(1, 1), lr=(1e-2, 1e-2),
                                                 lr_slots=(1, 1), confidence_threshold=0.5))
    assert res.depth.min() >= 1.9 and res.depth.max() <= 3.0
    assert np.allclose(np.linalg.norm(res.normal, axis=-1), 1, atol=1e-5)


def test_options_validate():
    with pytest.raises(OptionsError, match="iters"):
        RefinementOptions(scales=3).validate()
    with pytest.raises(OptionsError, match="window"):
        RefinementOptions(window=8).validate()
    with pytest.raises(OptionsError, match="solver"):
        RefinementOptions(solver="lbfgs").validate()


def test_refine_views_leaves_no_data_views_empty_with_a_warning():
    from engine.refinement.views import refine_views
    from engine.scene import SceneOptions, load_scene
    from tests.conftest import SAMPLES

    scene = load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=64))
    depths = [scene.gt_depth(v.index) for v in scene.views]
    confs = [np.ones(d.shape) for d in depths]
    confs[1][:] = 0.0
    opts = RefinementOptions(scales=2, fast_iters=(150, 60), iters=(1, 1), lr=(1e-2, 1e-2), lr_slots=(1, 1))
    with pytest.warns(UserWarning, match=f"view {scene.views[1].name}: .*zero confidence"):
        out = refine_views(scene, depths, [None] * len(depths), confs, opts)
    assert out[1] is None
    for i in (0, 2, 3, 4):
        gt = depths[i]
        assert np.all(out[i].depth > 0)
        assert np.median(np.abs(out[i].depth[gt > 0] - gt[gt > 0]) / gt[gt > 0]) < 0.01


def test_full_keeps_confident_patchmatch_estimates_and_refines_the_rest():
    from engine.refinement.guard import keep_confident

    depth = np.array([[1.0, 2.0], [0.0, 4.0]], np.float32)
    normal = np.zeros((2, 2, 3), np.float32)
    normal[..., 2] = -1
    confidence = np.array([[0.9, 0.05], [0.9, 0.1]], np.float32)
    refined = np.full((2, 2), 7.0, np.float32)
    refined_normal = np.zeros((2, 2, 3), np.float32)
    refined_normal[..., 0] = 1
    refined_confidence = np.full((2, 2), 0.3, np.float32)
    d, n, c = keep_confident(depth, normal, confidence, refined, refined_normal, refined_confidence, 0.1)
    # kept: confident estimates (c >= 0.1) that exist; a confident pixel without an estimate is refined
    np.testing.assert_array_equal(d, [[1.0, 7.0], [7.0, 4.0]])
    np.testing.assert_allclose(c, [[0.9, 0.3], [0.3, 0.1]], rtol=1e-6)
    assert n[0, 0, 2] == -1 and n[0, 1, 0] == 1 and n[1, 1, 2] == -1
    d, n, c = keep_confident(depth, normal, confidence, refined, refined_normal, refined_confidence, None)
    assert (d == 7.0).all() and (c == 0.3).all()  # the paper: refined everywhere
