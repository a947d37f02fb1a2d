"""The cloud of a streamed run stays on disk (engine/fusion/stream.py, engine/evaluation/chunked.py): fused.ply written
as fusion goes is write_fused_ply's file byte for byte, the cloud returned maps it and equals the in-memory cloud,
nothing is left half-written, the driver never holds the whole cloud, and the chunked evaluation gives the in-memory
evaluation's numbers to the last bit."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest

import engine.evaluation.chunked as chunked
import engine.fusion.cached as cached
import engine.fusion.stream as stream
from engine.evaluation import EvaluationOptions, PointIndex, evaluate_point_chunks, evaluate_points
from engine.fusion import FUSION_PRESETS, DiskCloud, FusedCloud, fuse, views_from_scene, write_fused_ply
from engine.fusion.kernel import output_arrays
from engine.io.ply import read_points
from engine.run.distributed.streamed import fuse_run_folder
from engine.run.folder import read_map, write_map
from engine.run.fused_maps import FusionRule
from engine.scene import load_scene
from tests.conftest import SAMPLES, make_noisy_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """sample_scenes/tiny and a run folder of its GT depth with outlier blobs, and confidence maps."""
    out = make_noisy_run(SAMPLES / "tiny", tmp_path_factory.mktemp("noisy"))
    scene = load_scene(SAMPLES / "tiny")
    rng = np.random.default_rng(1)
    for v in scene.views:
        write_map(out, "confidence", v.name, np.round(read_map(out, "counter", v.name) / 5 * rng.random(
            read_map(out, "counter", v.name).shape), 2))
    return scene, out


VANILLA = FusionRule("vanilla")


def _rule(tau: float | None) -> FusionRule:
    """vanilla (None) or fast at ``tau``."""
    return VANILLA if tau is None else FusionRule("fast", tau)

def _same_cloud(got: FusedCloud, want: FusedCloud) -> None:
    for f in dataclasses.fields(FusedCloud):
        a, b = getattr(got, f.name), getattr(want, f.name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), f.name


@pytest.mark.parametrize("tau", [None, 0.3])
def test_streamed_fused_ply_is_write_fused_ply(run, tau, tmp_path, monkeypatch):
    scene, out = run
    options = FUSION_PRESETS["pixels"].replace(max_num_pixels=500)
    want = fuse_run_folder(scene, out, options, _rule(tau))
    write_fused_ply(tmp_path / "want.ply", want)
    monkeypatch.setattr(cached, "CHUNK_POINTS", 1000)  # many chunks (a cluster of max_num_pixels fits one)
    got = fuse_run_folder(scene, out, options, _rule(tau), ply=tmp_path / "fused.ply")
    assert len(want) > 10 * 1000
    assert (tmp_path / "fused.ply").read_bytes() == (tmp_path / "want.ply").read_bytes()
    assert isinstance(got, DiskCloud)
    _same_cloud(got, want)
    # every attribute maps a file: nothing of the cloud is held in memory
    for f in dataclasses.fields(FusedCloud):
        value = getattr(got, f.name)
        assert not value.flags.owndata and not value.flags.writeable and _maps_a_file(value), f.name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fused.ply", "want.ply"]  # the positions' file is nameless
    np.testing.assert_array_equal(got.read_xyz(len(got) - 5, 100), want.xyz[-5:])
    _same_cloud(got.subset(np.arange(0, len(got), 7)), want.subset(np.arange(0, len(want), 7)))


@pytest.mark.parametrize("tau", [None, 0.3])
def test_an_in_process_run_fuses_its_views_into_the_ply_as_fuse_does(run, tau, tmp_path):
    """``deepc run --executor local`` fuses the views it holds straight into fused.ply (fuse_views_to_ply): the
    file is write_fused_ply(fuse(views)) byte for byte and the cloud equals fuse's."""
    scene, out = run
    options = FUSION_PRESETS["pixels"].replace(max_num_pixels=500)
    maps = [(read_map(out, "depth", v.name), read_map(out, "normal", v.name),
             None if tau is None else read_map(out, "confidence", v.name)) for v in scene.views]
    views = views_from_scene(scene, *(list(m) for m in zip(*maps, strict=True)), options.check_num_images)
    want = fuse(views, options)
    write_fused_ply(tmp_path / "want.ply", want)
    got = stream.fuse_views_to_ply(tmp_path / "fused.ply", views, options)
    assert isinstance(got, DiskCloud) and len(want) > 1000
    assert (tmp_path / "fused.ply").read_bytes() == (tmp_path / "want.ply").read_bytes()
    _same_cloud(got, want)


def _maps_a_file(array: np.ndarray) -> bool:
    while array is not None:
        if isinstance(array, np.memmap) or type(array).__name__ == "mmap":
            return True
        array = array.base
    return False


def _chunks(rng, sizes: list[int]) -> list[tuple]:
    """Kernel output arrays holding random points, ``sizes`` of them each (room for more)."""
    out = []
    for n in sizes:
        arrays = output_arrays(n + 3)
        xyz, nrm, rgb, nv, npx, conf, src = arrays
        xyz[:] = rng.normal(size=xyz.shape) * 10
        nrm[:] = rng.normal(size=nrm.shape)
        rgb[:] = rng.integers(0, 256, rgb.shape)
        nv[:], npx[:], src[:] = (rng.integers(0, 1000, nv.shape) for _ in range(3))
        conf[:] = np.where(rng.random(conf.shape) < 0.2, np.nan, rng.random(conf.shape))
        out.append((arrays, n))
    return out


@pytest.mark.parametrize("bound", [10 ** 9, 1234, 12, 0])  # room for longer, same, shorter headers (the body moves)
@pytest.mark.parametrize("sizes", [[], [0], [5, 0, 700, 333], [1200]])
def test_the_header_room_changes_no_byte(tmp_path, monkeypatch, bound, sizes):
    monkeypatch.setattr(stream, "MOVE_BLOCK", 4096)  # a move of several blocks
    chunks = _chunks(np.random.default_rng(len(sizes)), sizes)

    def produce(sink):
        for arrays, n in chunks:
            sink(arrays, n)

    got = stream.write_fused_stream(tmp_path / "a" / "fused.ply", produce, bound)
    fields = [np.concatenate([a[k][:n] for a, n in chunks]) if chunks else output_arrays(0)[k] for k in range(7)]
    want = FusedCloud(fields[0], fields[1], fields[2], fields[3], fields[5], fields[6], fields[4])
    write_fused_ply(tmp_path / "want.ply", want)
    assert (tmp_path / "a" / "fused.ply").read_bytes() == (tmp_path / "want.ply").read_bytes()
    _same_cloud(got, want)
    assert len(got) == sum(sizes)


def test_a_failed_fusion_leaves_no_file(tmp_path):
    chunks = _chunks(np.random.default_rng(0), [100])
    (tmp_path / "fused.ply").write_bytes(b"earlier")

    def produce(sink):
        sink(*chunks[0])
        raise RuntimeError("stopped")

    with pytest.raises(RuntimeError, match="stopped"):
        stream.write_fused_stream(tmp_path / "fused.ply", produce, 1000)
    assert [p.name for p in tmp_path.iterdir()] == ["fused.ply"] and (tmp_path / "fused.ply").read_bytes() == b"earlier"


def test_streamed_fusion_never_holds_the_cloud(run, tmp_path, monkeypatch):
    """Traced allocations (numpy's) of the streamed fusion stay far below those of the cached fusion that joins the
    cloud, by at least the cloud (the views' slots are the same in both)."""
    scene, out = run
    options = FUSION_PRESETS["pixels"].replace(max_num_pixels=500)
    monkeypatch.setattr(cached, "CHUNK_POINTS", 1000)
    fuse_run_folder(scene, out, options, VANILLA, cache_views=None, ply=tmp_path / "warm.ply")  # compiled, files cached

    def peak(**kwargs):
        tracemalloc.start()
        try:
            cloud = fuse_run_folder(scene, out, options, VANILLA, cache_views=None, **kwargs)
            return tracemalloc.get_traced_memory()[1], cloud
        finally:
            tracemalloc.stop()

    joined, cloud = peak()
    streamed, _ = peak(ply=tmp_path / "fused.ply")
    size = sum(getattr(cloud, f.name).nbytes for f in dataclasses.fields(cloud))
    assert size > 3 << 20 and streamed + size < joined, (streamed, joined, size)


@pytest.fixture(scope="module")
def cloud(run, tmp_path_factory):
    scene, out = run
    return fuse_run_folder(scene, out, FUSION_PRESETS["pixels"], VANILLA,
                           ply=tmp_path_factory.mktemp("c") / "fused.ply")


@pytest.mark.parametrize("views", [False, True])
@pytest.mark.parametrize("sizes", [(1 << 18, 1 << 19), (4000, 9000), (777, 5000)])  # chunk, slab
def test_chunked_evaluation_is_the_in_memory_one(run, cloud, monkeypatch, views, sizes):
    scene = run[0]
    monkeypatch.setattr(chunked, "CHUNK_POINTS", sizes[0])
    monkeypatch.setattr(chunked, "SLAB_POINTS", sizes[1])
    gt, gt_views = read_points(scene.gt_points_path), scene.gt_views() if views else None
    options = EvaluationOptions(tolerances=(0.002, 0.01, 0.02, 0.05))
    want = evaluate_points(np.asarray(cloud.xyz, np.float64), gt, options, gt_views)
    got = evaluate_point_chunks(len(cloud), cloud.read_xyz, gt, options, gt_views)
    assert got == want and 0 < want.accuracy[0] < 100 and 0 < want.completeness[0] < 100
    assert (max(want.unobserved) > 0) == views


def test_chunked_evaluation_of_nothing_and_of_far_points():
    rng = np.random.default_rng(3)
    gt = rng.random((500, 3))
    far = np.array([[1e6, -1e6, 1e6]])  # the voxel box has more than 2^62 cells: no row-major keys
    for recon in (np.zeros((0, 3)), gt[:50] + 100.0, np.concatenate([gt[:50] + 0.003, gt[50:60] + 100.0]),
                  np.concatenate([gt[:50] + 0.003, far])):
        assert evaluate_point_chunks(len(recon), lambda s, c, r=recon: r[s:s + c], gt) == evaluate_points(recon, gt)


def test_chunked_evaluation_holds_no_copy_of_the_cloud(monkeypatch):
    """Traced allocations while scoring a cloud of many chunks and slabs stay below half its (N, 3) float64 positions
    (the ground truth's index is built before), a fraction of the in-memory evaluation's."""
    rng = np.random.default_rng(5)
    recon = rng.random((200_000, 3)) * [3.0, 1.0, 1.0]
    gt = PointIndex(rng.random((5_000, 3)) * [3.0, 1.0, 1.0])
    monkeypatch.setattr(chunked, "CHUNK_POINTS", 5_000)
    monkeypatch.setattr(chunked, "SLAB_POINTS", 10_000)
    options = EvaluationOptions(tolerances=(0.01, 0.05))
    tracemalloc.start()
    try:
        want = evaluate_points(recon, gt, options)
        in_memory = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        got = evaluate_point_chunks(len(recon), lambda s, c: recon[s:s + c].copy(), gt, options)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert got == want and peak < recon.nbytes / 2 and peak < in_memory / 4, (peak, in_memory, recon.nbytes)


def test_the_rerun_stream_logs_a_cloud_on_disk(cloud, tmp_path):
    """The fusion stage's observers get the DiskCloud (a streamed run with --stream)."""
    pytest.importorskip("rerun")
    from workbench.rerun.recording import Recording
    from workbench.rerun.stream import RerunStream

    recording = Recording(tmp_path / "run.rrd")
    scene = load_scene(SAMPLES / "tiny")
    views = [(v.name, v.camera, np.zeros((v.camera.height, v.camera.width, 3), np.float32), []) for v in scene.views]
    RerunStream(recording.rec, views, None, pass_iterations=lambda p: 1).on_stage("fusion", cloud=cloud,
                                                                                     pipeline="vanilla")
    recording.finish()
    assert (tmp_path / "run.rrd").stat().st_size > len(cloud) * 12  # float32 positions at least
