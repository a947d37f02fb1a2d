"""ETH3D-style evaluation (Schöps et al. 2017): scores, voxel averaging, unobserved space, ETH3D format, bad input."""

from __future__ import annotations

import argparse
import functools
import json

import numpy as np
import pytest

from engine.core.camera import Camera
from engine.core.errors import DeepCError, OptionsError
from engine.evaluation import (
    EvaluationOptions,
    PointIndex,
    classify_beam,
    evaluate_eth3d,
    evaluate_file,
    evaluate_points,
    free_space_margin,
    load_eth3d_mlp,
    parse_tolerances,
)
from engine.io.ply import write_ply
from engine.scene import load_scene
from support.evaluation_reference import classify_beam_reference, free_space_margin_reference
from support.synthetic_scan import make_synthetic_eth3d, sample_synthetic_reconstruction
from tests.conftest import SAMPLES
from workbench.cli.eval import cmd_eval

TOL = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)


def _grid_plane(step=0.005, size=1.0, z=0.0):
    a = np.arange(0, size, step)
    X, Y = np.meshgrid(a, a)
    return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)


def test_perfect_and_shifted():
    gt = _grid_plane()
    res = evaluate_points(gt, gt)
    assert res.accuracy == [100.0] * 6 and res.completeness == [100.0] * 6 and res.f1 == [100.0] * 6
    shifted = gt + [0, 0, 0.015]
    res = evaluate_points(shifted, gt)
    assert res.accuracy[0] == 0 and res.completeness[0] == 0 and res.f1[0] == 0
    assert res.accuracy[1] == 100 and res.completeness[1] == 100
    assert list(res.to_dict()) == ["tolerances", "accuracy", "completeness", "f1"]
    assert res.to_dict()["tolerances"] == list(TOL)
    assert "F1" in res.format_table()


def test_prepared_ground_truth_scores_the_same():
    # The viewer scores many clouds against one GT through a PointIndex built once: same numbers.
    rng = np.random.default_rng(3)
    gt = _grid_plane(step=0.01)
    recon = np.concatenate([gt[::3] + rng.normal(0, 0.01, (len(gt[::3]), 3)), rng.random((500, 3))])
    index = PointIndex(gt)
    for cloud in (recon, recon[:0], recon[::5]):
        assert evaluate_points(cloud, index).to_dict() == evaluate_points(cloud, gt).to_dict()
    with pytest.raises(DeepCError, match="ground truth"):
        PointIndex(np.full((3, 3), np.nan))


def test_voxel_averaging_cancels_density():
    # Two GT patches, one 16x denser (both occupy every 5 cm voxel); the reconstruction covers only the
    # sparse one -> 50 % (voxels count equally), not ~6 % (points counting equally).
    sparse = _grid_plane(step=0.02, size=0.5)
    dense = _grid_plane(step=0.005, size=0.5) + [5.0, 0, 0]
    res = evaluate_points(sparse, np.concatenate([sparse, dense]),
                          EvaluationOptions(tolerances=(0.05,), voxel_size=0.05))
    assert res.completeness[0] == pytest.approx(50.0, abs=1.0)
    assert res.accuracy[0] == 100.0


def test_empty_reconstruction_and_other_scene():
    gt = _grid_plane()
    res = evaluate_points(np.zeros((0, 3)), gt)
    assert res.f1 == [0.0] * 6 and res.accuracy == [0.0] * 6 and res.completeness == [0.0] * 6
    assert "empty" in res.notes[0]
    res = evaluate_points(gt + 1000.0, gt)  # GT of another scene: no overlap
    assert res.f1 == [0.0] * 6
    assert "another scene" in res.notes[0]
    with pytest.raises(DeepCError, match="no points"):
        evaluate_points(gt, np.zeros((0, 3)))
    with pytest.raises(DeepCError, match="non-finite"):
        evaluate_points(np.array([[np.nan, 0, 0]]), gt)


@pytest.mark.parametrize("tolerances", [(0.0, 0.1), (-0.01,), (), (float("inf"),)])
def test_tolerances_must_be_positive(tolerances):
    with pytest.raises(OptionsError, match="tolerance"):
        evaluate_points(_grid_plane(), _grid_plane(), EvaluationOptions(tolerances=tolerances))


def test_parse_tolerances():
    assert parse_tolerances("0.01, 0.02") == (0.01, 0.02)
    with pytest.raises(OptionsError):
        parse_tolerances("0.01,abc")
    with pytest.raises(OptionsError):
        parse_tolerances("0,-1")


def _ply_bytes(header_lines, body=b""):
    return ("\n".join(["ply", "format binary_little_endian 1.0", *header_lines, "end_header"]) + "\n").encode() + body


def test_bad_ply_inputs(tmp_path):
    gt = tmp_path / "gt.ply"
    write_ply(gt, _grid_plane())
    no_vertex = tmp_path / "faces_only.ply"
    no_vertex.write_bytes(_ply_bytes(["element face 0", "property list uchar int vertex_indices"]))
    with pytest.raises(DeepCError, match="vertex"):
        evaluate_file(no_vertex, gt)
    no_xyz = tmp_path / "no_xyz.ply"
    no_xyz.write_bytes(_ply_bytes(["element vertex 1", "property float a", "property float b"], b"\0" * 8))
    with pytest.raises(DeepCError, match="x/y/z|no x"):
        evaluate_file(no_xyz, gt)
    zero = tmp_path / "zero.ply"
    zero.write_bytes(_ply_bytes(["element vertex 0", "property float x", "property float y", "property float z"]))
    res = evaluate_file(zero, gt)
    assert res.f1 == [0.0] * 6 and res.notes
    with pytest.raises(DeepCError, match="not found"):
        evaluate_file(tmp_path / "missing.ply", gt)


def test_double_ply_reads_correctly(tmp_path):
    # The official program scores double-coordinate PLYs as 0; we must read them.
    pts = _grid_plane() + [100.123456789, -50.5, 3.25]
    f4, f8 = tmp_path / "f4.ply", tmp_path / "f8.ply"
    write_ply(f4, pts)
    write_ply(f8, pts, coordinate_dtype="f8", normals=np.zeros_like(pts), rgb=np.zeros((len(pts), 3), np.uint8))
    a, b = evaluate_file(f4, f4), evaluate_file(f8, f4)
    assert a.f1 == b.f1 == [100.0] * 6


def _box_camera(width=64, height=48):
    R = np.eye(3)
    return Camera.from_params(width, height, 50.0, 50.0, width / 2, height / 2, R, np.zeros(3))


def test_unobserved_space_rule():
    cam = _box_camera()
    depth = np.full((48, 64), 4.0, np.float32)  # a wall at z = 4 seen by the camera at the origin
    depth[:, :8] = 0  # unknown GT in a strip
    X = cam.backproject(depth)
    gt = X[depth > 0]
    rays = cam.pixel_rays()[10:40:3, 12:60:3].reshape(-1, 3)
    behind = rays * 4.5  # behind the wall: unobserved, must not count
    front = rays * 3.0  # floating in observed free space: inaccurate
    on = gt[::7]
    views = [(cam, depth)]
    res_b = evaluate_points(np.concatenate([on, behind]), gt, gt_views=views)
    assert res_b.accuracy == [100.0] * 6
    assert res_b.unobserved[0] > 0
    res_f = evaluate_points(np.concatenate([on, front]), gt, gt_views=views)
    assert res_f.accuracy[0] < 100.0
    res_plain = evaluate_points(np.concatenate([on, behind]), gt)  # without views behind points do count
    assert res_plain.accuracy[0] < 100.0
    # Free-space margin: 1 m in front of the wall along the ray, -inf where no GT.
    m = free_space_margin(front[:3], views)
    np.testing.assert_allclose(m, 1.0 * np.linalg.norm(rays[:3], axis=1), rtol=1e-6)
    left = cam.pixel_rays()[20, 2] * 3.0
    assert free_space_margin(left[None], views)[0] == -np.inf


def test_free_space_kernel_matches_reference():
    scene = load_scene(SAMPLES / "fountain_p11")
    views = [(scene.views[i].camera, scene.gt_depth(i)) for i in (0, 3, 7)]
    rng = np.random.default_rng(0)
    gt_pts = scene.views[0].camera.backproject(views[0][1])
    gt_pts = gt_pts[np.isfinite(gt_pts[..., 0])]
    pts = gt_pts[rng.choice(len(gt_pts), 400)] + rng.normal(0, 0.3, (400, 3))
    pts = np.concatenate([pts, rng.uniform(-20, 20, (100, 3))])
    np.testing.assert_allclose(free_space_margin(pts, views), free_space_margin_reference(pts, views), rtol=1e-9)
    # GT depth given as functions that read it (a run's evaluation reads each map only while packing): same margins
    readers = [(scene.views[i].camera, functools.partial(scene.gt_depth, i)) for i in (0, 3, 7)]
    np.testing.assert_array_equal(free_space_margin(pts, readers), free_space_margin(pts, views))


@pytest.fixture(scope="module")
def coarse_eth3d(tmp_path_factory):
    """Small synthetic ETH3D GT (4 mrad rays, a few 10k points) with a beam wide enough for it."""
    folder = tmp_path_factory.mktemp("eth3d")
    mlp = make_synthetic_eth3d(folder, step_mrad=4.0)
    return mlp, EvaluationOptions(beam_start_radius=0.008)


def test_beam_kernel_matches_reference(coarse_eth3d):
    mlp, opts = coarse_eth3d
    scan = load_eth3d_mlp(mlp)[0]
    rng = np.random.default_rng(1)
    R, t = scan.global_T_scan[:3, :3], scan.global_T_scan[:3, 3]
    recon = sample_synthetic_reconstruction(600, noise=0.01, outlier_fraction=0.2, seed=2).astype(np.float64)
    local = (recon - t) @ R
    local = np.concatenate([local, scan.points[rng.choice(len(scan.points), 50)] * 1.002])
    tol = np.array(TOL)
    f, fl = classify_beam(local, scan, tol, opts)
    fr, flr = classify_beam_reference(local, scan.points, tol, opts.beam_start_radius,
                                      opts.beam_divergence_halfangle_deg)
    assert (f != fr).sum() <= 1 and (fl != flr).sum() <= 1  # float32 cell binning may differ at a border
    assert (fr < len(tol)).sum() > 50 and flr.sum() > 50  # the test exercises both outcomes


def test_eth3d_end_to_end(coarse_eth3d, tmp_path):
    mlp, opts = coarse_eth3d
    scans = load_eth3d_mlp(mlp)
    merged = np.concatenate([s.points.astype(np.float64) @ s.global_T_scan[:3, :3].T + s.global_T_scan[:3, 3]
                             for s in scans])
    res = evaluate_eth3d(merged, mlp, opts)
    assert res.completeness == [100.0] * 6
    assert min(res.accuracy) > 99.0
    recon = sample_synthetic_reconstruction(20000, seed=3)
    res = evaluate_eth3d(recon, scans, opts)
    assert 0 < res.f1[0] < res.f1[-1] <= 100
    below = recon.copy()
    below[:, 2] = -0.8 - np.abs(below[:, 2])  # far under the plate: no scanner sees there
    assert evaluate_eth3d(below, scans, opts).accuracy == [0.0] * 6  # nothing observed -> 0, honest
    assert evaluate_eth3d(np.zeros((0, 3)), scans, opts).f1 == [0.0] * 6


def test_bad_mlp(tmp_path, coarse_eth3d):
    with pytest.raises(DeepCError, match="not found"):
        load_eth3d_mlp(tmp_path / "none.mlp")
    bad = tmp_path / "bad.mlp"
    bad.write_text("<MeshLabProject><MeshGroup>")
    with pytest.raises(DeepCError, match="XML"):
        load_eth3d_mlp(bad)
    bad.write_text('<MeshLabProject><MeshGroup><MLMesh label="a" filename="a.ply"><MLMatrix44>'
                   "1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1</MLMatrix44></MLMesh></MeshGroup></MeshLabProject>")
    with pytest.raises(DeepCError, match="last row"):
        load_eth3d_mlp(bad)
    bad.write_text('<MeshLabProject><MeshGroup><MLMesh label="a" filename="missing.ply"><MLMatrix44>'
                   "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</MLMatrix44></MLMesh></MeshGroup></MeshLabProject>")
    with pytest.raises(DeepCError, match="missing.ply"):
        load_eth3d_mlp(bad)
    bad.write_text("<MeshLabProject><MeshGroup></MeshGroup></MeshLabProject>")
    with pytest.raises(DeepCError, match="no scans"):
        load_eth3d_mlp(bad)


def test_cmd_eval(tmp_path, capsys, coarse_eth3d):
    gt = tmp_path / "gt.ply"
    write_ply(gt, _grid_plane())
    rec = tmp_path / "rec.ply"
    write_ply(rec, _grid_plane() + [0, 0, 0.015])
    out = tmp_path / "out" / "eval.json"
    args = argparse.Namespace(recon=str(rec), gt=str(gt), tolerances="0.01,0.02", json=str(out))
    assert cmd_eval(args) == 0
    printed = capsys.readouterr().out
    assert "accuracy" in printed and "F1" in printed
    data = json.loads(out.read_text())
    assert data["tolerances"] == [0.01, 0.02] and data["f1"] == [0.0, 100.0]
    with pytest.raises(OptionsError):
        cmd_eval(argparse.Namespace(recon=str(rec), gt=str(gt), tolerances="0,0.1", json=None))
    mlp, _ = coarse_eth3d
    assert cmd_eval(argparse.Namespace(recon=str(rec), gt=str(mlp), tolerances="0.05", json=None)) == 0
