"""The per-view work on Dask (engine/distributed): the same maps as the in-process pipeline on a LocalCluster of two
workers, after a worker is killed mid-task, and after an interrupted run resumed with the other executor; an
unreachable scheduler is one line and exit 2. Every wait has a timeout; the cluster is always shut down."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
from conftest import SAMPLES, RecordingExecutor

from engine.patchmatch import PatchMatchOptions
from engine.run.checkpoint import CHECKPOINT_DIR, PatchMatchCheckpoint
from engine.run.distributed import LocalExecutor
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.scene import SceneOptions, load_scene

pytest.importorskip("distributed")
pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

# 2 levels x (photometric + 1 geometric) passes over 5 views; fast: confidence too
OPTIONS = PipelineOptions(pipeline="fast", patchmatch=PatchMatchOptions(levels=2, geom_passes=1, iterations=1, seed=7))
SCENE = SceneOptions(max_image_size=96)


@pytest.fixture(scope="module")
def scene():
    return load_scene(SAMPLES / "tiny", SCENE)


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    run_pipeline(scene, out, OPTIONS)
    return out


@pytest.fixture(scope="module")
def cluster():
    from engine.run.distributed.dask_executor import DaskExecutor

    executor = DaskExecutor(workers=2, stall_timeout=120)
    try:
        yield executor
    finally:
        executor.close()


def _outputs(out: Path) -> dict[str, bytes]:
    """Every map and the fused cloud, by path relative to the run folder."""
    files = [p for p in out.rglob("*") if p.is_file() and (p.suffix == ".bin" or p.name == "fused.ply")]
    return {str(p.relative_to(out)): p.read_bytes() for p in files}


#: metrics.json entries that say how good the run is (the driver of an executor run streams them from the run folder)
QUALITY = ("fused_points", "eval", "depth", "depth_per_view", "confidence_auc", "confidence_auc_per_view",
           "confidence_kept_pct", "views")


def _assert_same(out: Path, reference: Path, maps: int = 5 * 5) -> None:
    got, want = _outputs(out), _outputs(reference)
    assert sorted(got) == sorted(want) and len(want) >= maps + 1  # depth, normal, cost, counter (, confidence)
    assert [k for k in want if got[k] != want[k]] == []  # maps and fused.ply
    assert not list(out.rglob("*.tmp")), "a partial file was left"
    assert not (out / CHECKPOINT_DIR).exists()
    got, want = (json.loads((folder / "metrics.json").read_text()) for folder in (out, reference))
    assert "depth" in want and [k for k in QUALITY if json.dumps(got.get(k)) != json.dumps(want.get(k))] == []


def test_local_executor_tasks_give_the_same_maps(scene, reference, tmp_path):
    run_pipeline(scene, tmp_path, OPTIONS, executor=LocalExecutor())
    _assert_same(tmp_path, reference)


def test_two_dask_workers_give_the_same_maps_and_progress(scene, reference, cluster, tmp_path):
    assert cluster.workers == 2 and cluster.threads >= 1
    calls = []
    events = []

    class Observer:
        def on_iteration(self, event):
            events.append((event.level, event.pass_index, event.view))

    run_pipeline(scene, tmp_path, OPTIONS, executor=cluster, observer=Observer(),
                 progress=lambda d, done, n: calls.append((d, done, n)))
    _assert_same(tmp_path, reference)
    assert [c for c in calls if c[1] == c[2]] == [(f"level {lv} {k}", 5, 5) for lv in (1, 0)
                                                  for k in ("photometric", "geometric")]
    assert sorted(events) == sorted((lv, p, i) for lv in (1, 0) for p in (0, 1) for i in range(5))
    assert cluster.dashboard and cluster.dashboard.startswith("http")


def test_vanilla_on_two_workers_streams_the_same_cloud_and_metrics(scene, cluster, tmp_path):
    """The driver reads no map back: fusion goes through its bounded cache of views, the metrics view by view."""
    vanilla = PipelineOptions(pipeline="vanilla", patchmatch=OPTIONS.patchmatch)
    run_pipeline(scene, tmp_path / "local", vanilla)
    result = run_pipeline(scene, tmp_path / "dask", vanilla, executor=cluster)
    assert result.maps == [] and result.counter == [] and len(result.cloud) > 100
    _assert_same(tmp_path / "dask", tmp_path / "local", maps=5 * 4)


def test_confidence_tasks_return_the_refinement_weights(scene, reference, cluster, tmp_path):
    """``full`` refines with the confidence before the back-facing rule: the tasks return it, equal to the
    in-process stage's."""
    import shutil

    from engine.patchmatch import ViewMaps
    from engine.run.distributed.driver import run_confidence_tasks
    from engine.run.folder import read_map
    from engine.run.pipeline import confidence_stage

    shutil.copytree(reference, tmp_path, dirs_exist_ok=True)
    confidence, raw = run_confidence_tasks(scene, tmp_path, OPTIONS.confidence, cluster, want_raw=True)
    maps = [ViewMaps(read_map(reference, "depth", v.name), read_map(reference, "normal", v.name), None, None)
            for v in scene.views]
    counter = [read_map(reference, "counter", v.name).astype(np.uint8) for v in scene.views]
    want_raw = []
    want = confidence_stage(scene, maps, counter, OPTIONS.confidence, raw=want_raw)
    assert all(np.array_equal(a, b) for a, b in zip(confidence, want, strict=True))
    assert raw is not None and all(np.array_equal(a, b) for a, b in zip(raw, want_raw, strict=True))


def test_refinement_tasks_give_the_same_refined_maps(scene, reference, cluster):
    """``full``: Rossi et al. 2020's refinement per view as a task, from the maps in the run folder."""
    from engine.refinement.options import RefinementOptions
    from engine.refinement.views import refine_views
    from engine.run.distributed.driver import run_refinement_tasks
    from engine.run.folder import read_map

    cheap = RefinementOptions(scales=2, fast_iters=(60, 40), iters=(10, 10), lr=(0.01, 0.01), lr_slots=(1, 1))
    names = [v.name for v in scene.views]
    depth, normal, confidence = ([read_map(reference, kind, n) for n in names]
                                 for kind in ("depth", "normal", "confidence"))
    done = []
    got = run_refinement_tasks(scene, reference, confidence, cheap, cluster, lambda i, n, r: done.append(i))
    want = refine_views(scene, depth, normal, confidence, cheap)
    assert sorted(done) == list(range(5)) and all(r is not None for r in want)
    assert all(np.array_equal(a.depth, b.depth) and np.array_equal(a.normal, b.normal)
               for a, b in zip(got, want, strict=True))


class _KillOnce:
    """A task wrapper that kills its worker process (like a machine going down) while the first try of job
    ``target`` runs; ``marker`` records that it did."""

    def __init__(self, fn, target: int, marker: str):
        self.fn, self.target, self.marker = fn, target, marker

    def __call__(self, job):
        if job.view == self.target and not os.path.exists(self.marker):
            Path(self.marker).write_text(str(os.getpid()))
            threading.Timer(0.05, os._exit, (1,)).start()  # mid-task
            time.sleep(60)
        return self.fn(job)


class _Killing:
    """An executor that kills a worker during the first geometric pass of view 2."""

    def __init__(self, inner, marker: Path):
        self.inner, self.marker, self.workers, self.threads = inner, marker, inner.workers, inner.threads

    def map(self, fn, jobs, on_result=None):
        if jobs and getattr(jobs[0], "pass_index", 0) == 1 and getattr(jobs[0], "level", 0) == 1:
            fn = _KillOnce(fn, 2, str(self.marker))
        return self.inner.map(fn, jobs, on_result)


def test_a_worker_killed_mid_task_changes_nothing(scene, reference, cluster, tmp_path):
    import test_dask_executor

    cloudpickle.register_pickle_by_value(test_dask_executor)  # the wrapper runs on workers that cannot import tests
    marker = tmp_path / "killed"
    out = tmp_path / "run"
    run_pipeline(scene, out, OPTIONS, executor=_Killing(cluster, marker))
    assert marker.is_file()
    _assert_same(out, reference)
    deadline = time.monotonic() + 60
    while len(cluster.client.scheduler_info()["workers"]) < 2 and time.monotonic() < deadline:
        time.sleep(0.5)  # the nanny restarts the killed worker


class _Interrupt:
    def __init__(self, after: int):
        self.after, self.calls = after, 0

    def __call__(self, description: str, done: int, total: int) -> None:
        if done:
            self.calls += 1
            if self.calls == self.after:
                raise KeyboardInterrupt


@pytest.mark.parametrize("first", ["dask", "local"])
def test_resume_works_across_executors(scene, reference, cluster, tmp_path, first):
    executors = {"dask": cluster, "local": None}
    folder = tmp_path / CHECKPOINT_DIR
    with pytest.raises(KeyboardInterrupt):  # stopped during the first geometric pass
        run_pipeline(scene, tmp_path, OPTIONS, executor=executors[first], progress=_Interrupt(7),
                     checkpoint=PatchMatchCheckpoint(folder))
    checkpoint = PatchMatchCheckpoint(folder, resume=True)
    second = executors["local" if first == "dask" else "dask"]
    run_pipeline(scene, tmp_path, OPTIONS, executor=second, checkpoint=checkpoint)
    # 7 of the 20 view-passes were saved and recorded: only the other 13 ran again (the dask driver verifies the
    # 2 states of the unfinished pass; its tasks read the finished pass's states themselves)
    assert checkpoint.stats.saved == 13 and checkpoint.stats.reused >= 2 and checkpoint.stats.rejected == 0
    _assert_same(tmp_path, reference)


def test_unreachable_scheduler_is_one_line_and_exit_2(tmp_path, capsys):
    from workbench.cli.main import main

    code = main(["run", str(SAMPLES / "tiny"), "--out", str(tmp_path / "out"), "--headless", "--executor", "dask",
                 "--scheduler", "tcp://127.0.0.1:9", "--max-image-size", "96"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("deepc: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9")
    assert not any(line.startswith("Traceback") for line in err)


def test_deepc_run_on_a_local_cluster_prints_its_dashboard(tmp_path, capsys):
    from workbench.cli.main import main

    code = main(["run", str(SAMPLES / "tiny"), "--out", str(tmp_path / "out"), "--headless", "--executor", "dask",
                 "--workers", "2", "--max-image-size", "64", "--levels", "1", "--geom-passes", "0",
                 "--iterations", "1"])
    err = capsys.readouterr().err
    assert code == 0 and (tmp_path / "out" / "fused.ply").is_file()
    assert "dask: 2 worker(s) on a LocalCluster on this machine" in err and "dashboard http" in err


def test_tasks_read_only_what_the_driver_recorded(scene, tmp_path):
    """A state whose bytes differ from the recorded SHA-256 is not used: the task fails instead of computing
    from a wrong input."""
    from engine.core.errors import DeepCError
    from engine.run.distributed.tasks import load_state, state_reader

    cp = PatchMatchCheckpoint(tmp_path)
    cp.save(0, 0, 0, {"Z": np.ones((4, 4), np.float32), "N": np.zeros((4, 4, 3), np.float32),
                      "C": np.zeros((4, 4), np.float32), "S": np.zeros((4, 4), np.uint32)})
    reader = state_reader(str(tmp_path), {"L0_P0/0.npz": "0" * 64})
    with pytest.warns(UserWarning, match="checksum"), pytest.raises(DeepCError, match="missing or damaged"):
        load_state(reader, 0, 0, 0, (4, 4))
    assert load_state(state_reader(str(tmp_path), cp.entries), 0, 0, 0, (4, 4)).depth.sum() == 16


def test_geometric_tasks_read_their_sources_depth_alone(scene, tmp_path):
    """A geometric pass and the counter maps read their own state whole and only the depth array of their source
    views' states, verified by its own digest; a damaged depth is an error, not a wrong input."""
    from engine.core.errors import DeepCError
    from engine.run.distributed.tasks import FinishJob, PassJob, depth_digest, load_depth

    executor = RecordingExecutor()
    run_pipeline(scene, tmp_path, PipelineOptions(pipeline="vanilla", patchmatch=OPTIONS.patchmatch),
                 executor=executor)
    geometric = [j for j in executor.jobs if isinstance(j, PassJob) and j.pass_index == 1]
    finish = [j for j in executor.jobs if isinstance(j, FinishJob)]
    assert len(geometric) == 10 and len(finish) == 5
    for job in geometric + finish:
        # a geometric pass reads the pass before it; the final maps the last pass of level 0
        at = (job.level, job.pass_index - 1) if isinstance(job, PassJob) else (0, job.pass_index)
        own = PatchMatchCheckpoint.file_name(*at, job.view)
        assert list(job.inputs) == [own]
        assert sorted(job.depths) == sorted(own.replace(f"/{job.view}.", f"/{j}.")
                                            for j in scene.views[job.view].source_views)
    folder = tmp_path / "states"
    cp = PatchMatchCheckpoint(folder)
    depth = np.arange(16, dtype=np.float32).reshape(4, 4)
    cp.save(0, 0, 3, {"Z": depth, "N": np.zeros((4, 4, 3), np.float32), "C": np.zeros((4, 4), np.float32),
                      "S": np.zeros((4, 4), np.uint32)})
    good = {"L0_P0/3.npz": depth_digest(depth)}
    assert np.array_equal(load_depth(str(folder), {}, good, 0, 0, 3, (4, 4)), depth)
    with pytest.raises(DeepCError, match="damaged"):
        load_depth(str(folder), {}, {"L0_P0/3.npz": depth_digest(depth + 1)}, 0, 0, 3, (4, 4))
