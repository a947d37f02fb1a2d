"""Runs of other MVS systems read as runs: COLMAP dense workspaces and OpenMVS densify folders, written here from
their documented layouts; a bad or partial folder is one line and exit 2."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES
from test_cli import _one_line_error, deepc

from engine.compare.comparison import compare_runs, reference_scene
from engine.compare.dmap import decode_dmap, read_dmap
from engine.compare.sources import match_names, open_run
from engine.core.errors import DeepCError
from engine.core.resample import resample_depth
from engine.io.dense import write_dense_map
from engine.scene import load_scene
from support.fake_run import make_fake_run
from support.foreign_runs import encode_dmap, write_colmap_run, write_openmvs_run

TINY = SAMPLES / "tiny"


@pytest.fixture(scope="module")
def tiny():
    scene = load_scene(TINY)
    return scene, {v.name: scene.gt_depth(v.index) for v in scene.views}


@pytest.fixture(scope="module")
def our_run(tmp_path_factory):
    return make_fake_run(TINY, tmp_path_factory.mktemp("ours"))


def test_a_dmap_reads_back_every_map_and_field():
    rng = np.random.default_rng(0)
    depth = rng.uniform(1, 5, (6, 8)).astype(np.float32)
    depth[0, 0] = 0
    normal = rng.normal(size=(6, 8, 3)).astype(np.float32)
    conf = rng.uniform(0, 1, (6, 8)).astype(np.float32)
    views = rng.integers(0, 255, (6, 8, 4)).astype(np.uint8)
    data = decode_dmap(encode_dmap("images/a b.jpg", depth, image_size=(16, 12), normal=normal, confidence=conf,
                                   views=views, view_ids=(3, 1, 7), depth_range=(0.5, 9.0)))
    assert data.image_name == "images/a b.jpg" and data.view_ids == [3, 1, 7]
    assert data.image_size == (16, 12) and data.depth_size == (8, 6) and data.depth_range == (0.5, 9.0)
    np.testing.assert_array_equal(data.depth, depth)
    np.testing.assert_array_equal(data.normal, normal)
    np.testing.assert_array_equal(data.confidence, conf)
    np.testing.assert_array_equal(data.views, views)
    np.testing.assert_array_equal(data.R, np.eye(3))


def test_a_depth_only_dmap_and_the_quantized_layout_read():
    depth = np.array([[1.0, 2.0], [0.0, 3.5]], np.float32)
    plain = decode_dmap(encode_dmap("x.png", depth))
    assert plain.normal is None and plain.confidence is None and plain.views is None
    # newer OpenMVS: 32-byte header (depth exponent, confidence scale), half depths scaled by 2^-exponent, uint8 conf
    header = struct.pack("<2sBb4I3f", b"DR", 1 | 4, 2, 2, 2, 2, 2, 0.5, 4.0, 2.0)
    body = (struct.pack("<H", 5) + b"x.png" + struct.pack("<I", 1) + struct.pack("<I", 0) + bytes(8 * 21)
            + (depth / 4).astype("<f2").tobytes() + np.array([255, 0, 51, 102], "u1").tobytes())
    quantized = decode_dmap(header + body)
    np.testing.assert_array_equal(quantized.depth, depth)
    np.testing.assert_allclose(quantized.confidence.ravel(), [2.0, 0.0, 0.4, 0.8], rtol=1e-6)


@pytest.mark.parametrize("cut, fragment", [(10, "shorter than its header"), (60, "ends inside the camera"),
                                           (-4, "ends inside the confidence map")])
def test_a_cut_dmap_is_one_line_naming_it(tmp_path, cut, fragment):
    data = encode_dmap("x.png", np.ones((4, 4), np.float32), confidence=np.ones((4, 4), np.float32))
    data = data[:cut]
    path = tmp_path / "depth0000.dmap"
    path.write_bytes(data)
    with pytest.raises(DeepCError) as err:
        read_dmap(path)
    message = str(err.value)
    assert str(path) in message and "\n" not in message
    assert fragment in message


def test_views_match_by_image_name():
    views = ["view_000.png", "sub/view_001.png", "a.jpg"]
    assert match_names(["../images/view_000.png", "/data/x/sub/view_001.png", "elsewhere/a.jpg", "b.jpg"], views) \
        == {"view_000.png": "../images/view_000.png", "sub/view_001.png": "/data/x/sub/view_001.png",
            "a.jpg": "elsewhere/a.jpg"}


def test_a_colmap_workspace_is_a_run_of_its_own_scene(tmp_path, tiny):
    scene, gt = tiny
    names = list(gt)
    ws = write_colmap_run(TINY, tmp_path / "ws", lambda n: gt[n] * 1.2, names, kind="photometric")
    geometric = names[1]
    write_dense_map(ws / "stereo" / "depth_maps" / f"{geometric}.geometric.bin", gt[geometric])
    run = open_run(ws)
    assert run.kind == "colmap" and run.scene_root == ws and sorted(run.keys) == sorted(names)
    np.testing.assert_array_equal(run.depth(geometric), gt[geometric])  # the geometric map wins
    np.testing.assert_allclose(run.depth(names[0]), gt[names[0]] * 1.2, rtol=1e-6)
    assert load_scene(run.scene_root).views[0].name == names[0]


def test_colmap_and_openmvs_runs_of_the_ground_truth_are_right_where_ours_is(tmp_path, tiny, our_run):
    scene, gt = tiny
    names = list(gt)
    ws = write_colmap_run(TINY, tmp_path / "ws", lambda n: gt[n], names)
    # OpenMVS at half the resolution, and one view short: compared at 80x60, the missing view listed
    half = {n: resample_depth(gt[n], (80, 60)) for n in names}
    mvs = write_openmvs_run(TINY, tmp_path / "mvs", lambda n: half[n], names[:-1])
    ours = open_run(our_run, "raw")
    with_colmap = compare_runs(ours, open_run(ws), scene, evaluate_fused=False)
    assert with_colmap.total.b_right == with_colmap.total.gt  # GT itself is right everywhere GT exists
    assert with_colmap.total.b_right_a_wrong > 0 and with_colmap.total.a_right_b_wrong == 0
    with_mvs = compare_runs(open_run(ws), open_run(mvs), scene, evaluate_fused=False)
    assert [v.size for v in with_mvs.views] == [(80, 60)] * 4 and with_mvs.only_a == [names[-1]]
    assert with_mvs.total.a_right == with_mvs.total.gt
    assert with_mvs.total.b_right == with_mvs.total.gt  # GT at half size, compared at that size


def test_the_scene_comes_from_a_deepc_run_or_a_foreign_folder_or_scene(tmp_path, tiny, our_run):
    _, gt = tiny
    mvs = open_run(write_openmvs_run(TINY, tmp_path / "mvs", lambda n: gt[n], list(gt)))
    assert reference_scene(open_run(our_run), mvs).root.resolve() == TINY.resolve()
    with pytest.raises(DeepCError, match="--scene"):
        reference_scene(mvs, mvs)
    assert reference_scene(mvs, mvs, TINY).name == "tiny"


def _bad_folders(root: Path, our_run: Path, gt: dict) -> dict[str, tuple[Path, str]]:
    """name -> (folder, what its one line says)."""
    names = list(gt)
    empty = root / "empty"
    empty.mkdir()
    no_maps = root / "no_maps"
    (no_maps / "stereo" / "depth_maps").mkdir(parents=True)
    bad_bin = write_colmap_run(TINY, root / "bad_bin", lambda n: gt[n], names)
    target = bad_bin / "stereo" / "depth_maps" / f"{names[2]}.geometric.bin"
    target.write_bytes(target.read_bytes()[:-8])
    cut = write_openmvs_run(TINY, root / "cut", lambda n: gt[n], names)
    (cut / "depth0001.dmap").write_bytes((cut / "depth0001.dmap").read_bytes()[:500])
    partial = root / "partial"
    shutil.copytree(our_run, partial)
    (partial / "stereo" / "depth_maps" / f"{names[3]}.bin").unlink()
    unfinished = root / "unfinished"
    shutil.copytree(our_run, unfinished)
    (unfinished / "metrics.json").unlink()
    return {"empty": (empty, "not a deepc run"), "no_maps": (no_maps, "without depth maps"),
            "bad_bin": (bad_bin, f"{names[2]}.geometric.bin: truncated"), "cut": (cut, "depth0001.dmap: truncated"),
            "partial": (partial, "partial run"), "unfinished": (unfinished, "unfinished deepc run"),
            "missing": (root / "nowhere", "no such folder")}


def test_bad_or_partial_folders_are_one_line_and_exit_2(tmp_path, tiny, our_run):
    for folder, fragment in _bad_folders(tmp_path, our_run, tiny[1]).values():
        with pytest.raises(DeepCError) as err:
            open_run(folder)
        assert fragment in str(err.value) and "\n" not in str(err.value)
    # through the command line, either side
    (tmp_path / "cli").mkdir()
    bad = _bad_folders(tmp_path / "cli", our_run, tiny[1])
    _one_line_error(deepc("compare", our_run, bad["cut"][0]), "depth0001.dmap", "truncated")
    _one_line_error(deepc("compare", bad["bad_bin"][0], our_run), "geometric.bin", "truncated")
