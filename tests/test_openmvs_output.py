"""Real OpenMVS output read as a run: a depth map DensifyPointCloud (v2.3.0, built from source) wrote for
sample_scenes/tiny (``tests/data/openmvs_tiny/README.txt``), a densify folder with an interrupted run's leftovers,
and dense clouds with OpenMVS's per-point list properties."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES

from engine.compare.comparison import compare_runs
from engine.compare.dmap import read_dmap
from engine.compare.sources import open_run
from engine.core.errors import DeepCError
from engine.core.resample import resample_depth
from engine.io.ply import read_ply, read_points
from engine.scene import load_scene
from support.fake_run import make_fake_run
from workbench.viewer.compare import CompareApp, open_comparison

TINY = SAMPLES / "tiny"
REAL = Path(__file__).parent / "data" / "openmvs_tiny"
VIEW = "view_000.png"
SIZE = (80, 60)  # DensifyPointCloud --resolution-level 1 on the 160x120 images


@pytest.fixture(scope="module")
def scene():
    return load_scene(TINY)


def test_a_real_dmap_is_its_view_of_the_scene(scene):
    data = read_dmap(REAL / "depth0000.dmap")
    view = next(v for v in scene.views if v.name == VIEW)
    assert data.image_name == f"../tiny/images/{VIEW}" and data.view_ids[0] == view.index
    assert data.image_size == data.depth_size == SIZE
    camera = view.camera.rescaled(*SIZE)
    # the same rays: OpenMVS puts pixel centres at integer coordinates, we at +0.5
    np.testing.assert_allclose(data.K, camera.K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]), atol=1e-9)
    np.testing.assert_allclose(data.R, camera.R, atol=1e-9)
    np.testing.assert_allclose(data.C, camera.center, atol=1e-9)
    valid = data.depth > 0
    assert 0.2 < valid.mean() < 0.8
    assert data.depth_range[0] <= data.depth[valid].min() and data.depth[valid].max() <= data.depth_range[1]
    # unit camera-frame normals facing the camera, a confidence map, no views map (v2.3.0's defaults)
    np.testing.assert_allclose(np.linalg.norm(data.normal[valid], axis=1), 1, atol=1e-5)
    rows, cols = np.mgrid[:SIZE[1], :SIZE[0]]
    rays = np.stack([cols, rows, np.ones_like(cols)], axis=-1) @ np.linalg.inv(data.K).T
    assert ((data.normal * rays).sum(axis=-1)[valid] < 0).all()
    assert data.confidence is not None and data.views is None
    # what it estimated is mostly the scene's GT depth
    gt = resample_depth(scene.gt_depth(view.index), SIZE)
    both = valid & (gt > 0)
    assert (np.abs(data.depth[both] - gt[both]) < 0.01 * gt[both]).mean() > 0.7


def test_a_densify_folder_with_an_interrupted_runs_leftovers_compares_its_final_map(tmp_path, scene):
    folder = tmp_path / "openmvs"
    folder.mkdir()
    shutil.copy(REAL / "depth0000.dmap", folder / "depth0000.dmap")
    # mid-run files DensifyPointCloud leaves when stopped: a geometric pass's map and a filter's (another format)
    shutil.copy(REAL / "depth0000.dmap", folder / "depth0001.geo.dmap")
    (folder / "depth0000.filtered.dmap").write_bytes(b"\x16\x00\x00\x00serialization::archive")
    run = open_run(folder)
    assert list(run.keys) == [f"../tiny/images/{VIEW}"] and run.sizes[f"../tiny/images/{VIEW}"] == SIZE
    normal = run.normal(f"../tiny/images/{VIEW}")
    assert normal.shape == (*SIZE[::-1], 3) and np.isfinite(normal).all()
    ours = open_run(make_fake_run(TINY, tmp_path / "ours"), "raw")  # GT depth: right wherever GT exists
    comparison = compare_runs(ours, run, scene, evaluate_fused=False)
    assert [v.name for v in comparison.views] == [VIEW] and comparison.views[0].size == SIZE
    assert comparison.only_a == [v.name for v in scene.views if v.name != VIEW]
    counts = comparison.total
    assert counts.a_right > 0.9 * counts.gt  # GT depth, less the edge pixels the fake run drops
    # B is right exactly where the real map is within 1 % of GT at its own size
    depth = read_dmap(REAL / "depth0000.dmap").depth
    gt = resample_depth(scene.gt_depth(scene.views[0].index), SIZE)
    known = (gt > 0) & (depth > 0)
    assert counts.b_right == int((np.abs(depth[known] - gt[known]) < 0.01 * gt[known]).sum()) > 0.25 * counts.gt


def test_the_viewer_compares_ours_with_the_real_openmvs_map(tmp_path):
    folder = tmp_path / "openmvs"
    folder.mkdir()
    shutil.copy(REAL / "depth0000.dmap", folder / "depth0000.dmap")
    comparison = open_comparison(make_fake_run(TINY, tmp_path / "ours"), folder, maps="raw")
    app = CompareApp(comparison, port=0, max_points=5_000)
    try:
        assert app.selected.name == VIEW and app.pixel_x.disabled  # the probe replays our PatchMatch only
        assert comparison.b.kind == "openmvs" and comparison.b.fused is None  # no cloud: nothing to score
        cases = app.clouds["b"].case
        assert len(cases) and (app.clouds["b"].view == comparison.views[0].index).all()
        app.set_colouring("A / B")
        assert app.switch_seconds and "A right, B wrong" in app.metrics.content
    finally:
        app.stop()


# OpenMVS v2.3.0's scene_dense.ply vertex element (its header, as DensifyPointCloud writes it)
DENSE_PROPERTIES = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                    ("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
PLY_TYPES = {"f4": "float32", "u1": "uint8", "u4": "uint32"}


def _dense_ply(fmt: str, xyz: np.ndarray, views: list[list[int]]) -> bytes:
    """A cloud with OpenMVS's vertex layout: scalars, then ``list uint8 uint32 view_indices`` and ``list uint8
    float32 view_weights`` of ``views[i]`` (weights 0.5 each), in ``fmt`` (ascii, binary_*_endian)."""
    header = [f"ply\nformat {fmt} 1.0\nelement vertex {len(xyz)}\n"]
    header += [f"property {PLY_TYPES[kind]} {name}\n" for name, kind in DENSE_PROPERTIES]
    header += ["property list uint8 uint32 view_indices\nproperty list uint8 float32 view_weights\nend_header\n"]
    order = ">" if fmt == "binary_big_endian" else "<"
    body = []
    for i, (point, ids) in enumerate(zip(xyz, views, strict=True)):
        scalars = [*point, i % 256, 7, 9, 0.0, 0.0, -1.0]
        if fmt == "ascii":
            body.append(" ".join(map(str, [*scalars, len(ids), *ids, len(ids), *[0.5] * len(ids)])) + "\n")
        else:
            body.append(struct.pack(order + "3f3B3fB", *scalars, len(ids)) + struct.pack(f"{order}{len(ids)}I", *ids)
                        + struct.pack(f"{order}B{len(ids)}f", len(ids), *[0.5] * len(ids)))
    return "".join(header).encode() + (b"".join(body) if fmt != "ascii" else "".join(body).encode())


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
def test_an_openmvs_dense_cloud_reads_past_its_per_point_view_lists(tmp_path, fmt):
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-5, 5, (300, 3)).astype(np.float32)
    views = [list(rng.integers(0, 11, rng.integers(0, 6))) for _ in range(300)]  # 0 to 5 views a point
    path = tmp_path / "scene_dense.ply"
    path.write_bytes(_dense_ply(fmt, xyz, views))
    np.testing.assert_allclose(read_points(path), xyz, rtol=1e-6)
    columns = read_ply(path)
    assert sorted(columns) == sorted(name for name, _ in DENSE_PROPERTIES)  # the lists are skipped
    np.testing.assert_array_equal(columns["red"], np.arange(300) % 256)
    assert columns["red"].dtype == np.uint8 and (columns["nz"] == -1).all()


def test_a_cut_dense_cloud_with_lists_is_one_line_naming_it(tmp_path):
    path = tmp_path / "scene_dense.ply"
    path.write_bytes(_dense_ply("binary_little_endian", np.ones((20, 3), np.float32), [[1, 2, 3]] * 20)[:-10])
    with pytest.raises(DeepCError) as err:
        read_points(path)
    assert str(path) in str(err.value) and "truncated" in str(err.value) and "\n" not in str(err.value)
