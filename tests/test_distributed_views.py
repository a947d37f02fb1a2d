"""A per-view task holds its view and its source views, not the scene (engine/distributed): the driver's jobs carry
only those views, their size does not grow with the number of views, and the tasks never read the sparse model."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import SAMPLES, RecordingExecutor

from engine.consistency import CounterOptions
from engine.patchmatch import PatchMatchOptions
from engine.refinement.options import RefinementOptions
from engine.run.distributed import LocalExecutor
from engine.run.distributed.driver import run_patchmatch_tasks, run_refinement_tasks
from engine.run.distributed.tasks import PassJob, PassResult, RefineJob
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.scene import SceneOptions, load_scene
from engine.synthetic import write_scene
from engine.synthetic.sequence import street_scene

PATCHMATCH = PatchMatchOptions(levels=2, geom_passes=1, iterations=1, seed=7)


class _JobsOnly:
    """An executor that keeps the jobs and runs nothing (PatchMatch tasks 'write' a state of made-up digests)."""

    workers, threads = 1, 0

    def __init__(self):
        self.jobs = []

    def map(self, fn, jobs, on_result=None):
        self.jobs.extend(jobs)
        out = [PassResult("0" * 64, 0.0, 0, "1" * 64) if isinstance(j, PassJob) else None for j in jobs]
        for k, r in enumerate(out):
            if on_result is not None:
                on_result(k, r)
        return out


def _jobs(scene, tmp_path) -> list:
    executor = _JobsOnly()
    run_patchmatch_tasks(scene, tmp_path / "run", PATCHMATCH, CounterOptions(), executor, read_back=False)
    zero = [np.zeros((v.camera.height, v.camera.width), np.float32) for v in scene.views]
    run_refinement_tasks(scene, tmp_path / "run", zero, RefinementOptions(), executor)
    return executor.jobs


def test_a_job_carries_its_view_and_its_source_views(tmp_path):
    scene = load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=96))
    jobs = _jobs(scene, tmp_path)
    assert len(jobs) == 5 * 4 + 5 + 5
    for job in jobs:
        view = scene.views[job.view]
        want = [job.view] if isinstance(job, RefineJob) else [job.view, *view.source_views]
        assert list(job.scene.views) == want
        assert job.scene.views[job.view].camera.to_dict() == view.camera.to_dict()


@pytest.mark.slow
def test_jobs_do_not_grow_with_the_number_of_views(tmp_path):
    """The jobs of a view of a street sequence weigh the same in a sequence of 12 and of 36 views (the scene, loaded
    by the driver alone, grows: cameras, sparse points)."""
    sizes = {}
    for n in (12, 36):
        write_scene(street_scene(n, 64, 48), tmp_path / f"street{n}")
        scene = load_scene(tmp_path / f"street{n}", SceneOptions(num_source_views=4))
        jobs = [j for j in _jobs(scene, tmp_path / f"jobs{n}") if 2 <= j.view < 10 and isinstance(j, PassJob)]
        sizes[n] = max(len(pickle.dumps(j.scene)) for j in jobs), max(len(pickle.dumps(j)) for j in jobs)
    assert sizes[36][0] <= sizes[12][0] + 16 and sizes[36][1] <= sizes[12][1] + 64 and sizes[36][0] < 6000


@pytest.mark.slow
def test_tasks_never_read_the_sparse_model(tmp_path, monkeypatch):
    """The driver loads the scene; the tasks (here in this process) work from their jobs' views alone."""
    import engine.io.colmap_model
    import engine.scene

    scene = load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=96))

    def refuse(*args, **kwargs):
        raise AssertionError("a task read the sparse model")

    monkeypatch.setattr(engine.io.colmap_model, "read_sparse_model", refuse)
    monkeypatch.setattr(engine.scene, "read_sparse_model", refuse)
    monkeypatch.setattr(engine.scene, "load_scene", refuse)
    result = run_pipeline(scene, tmp_path, PipelineOptions(pipeline="vanilla", patchmatch=PATCHMATCH),
                          executor=LocalExecutor())
    assert len(result.cloud) > 100



@pytest.mark.slow
@pytest.mark.parametrize("backfacing_rule", [False, True])
def test_full_refines_with_weights_its_tasks_read(tmp_path, backfacing_rule):
    """``full`` as tasks: the refinement's weights before the back-facing rule go from the confidence tasks to the
    refinement tasks through the run folder (no map in a job, the folder removed after), and the maps are the
    in-process pipeline's byte for byte."""
    from engine.run.distributed.driver import RAW_CONFIDENCE_DIR

    scene = load_scene(SAMPLES / "tiny", SceneOptions(max_image_size=64))
    cheap = RefinementOptions(scales=2, fast_iters=(60, 40), iters=(10, 10), lr=(0.01, 0.01), lr_slots=(1, 1),
                              backfacing_rule=backfacing_rule)
    options = PipelineOptions(pipeline="full", patchmatch=PATCHMATCH, refinement=cheap)
    run_pipeline(scene, tmp_path / "local", options)
    executor = RecordingExecutor()
    run_pipeline(scene, tmp_path / "tasks", options, executor=executor)
    refine = [j for j in executor.jobs if isinstance(j, RefineJob)]
    assert len(refine) == 5 and all((j.confidence is None) != backfacing_rule for j in refine)
    assert not (tmp_path / "tasks" / RAW_CONFIDENCE_DIR).exists()
    files = sorted(p.relative_to(tmp_path / "local") for p in (tmp_path / "local").rglob("*")
                   if p.suffix == ".bin" or p.name == "fused.ply")
    assert len(files) > 5 * 6
    assert [f for f in files if (tmp_path / "local" / f).read_bytes() != (tmp_path / "tasks" / f).read_bytes()] == []


async def _asyncio_tasks() -> int:
    import asyncio

    return len(asyncio.all_tasks())


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_dask_waits_keep_one_waiter_per_task_and_fail_a_stalled_stage():
    """A stage of many short tasks leaves no waiters behind (a wait with a timeout every poll once left one per
    pending task each time: hundreds of MB in the driver of a long run), and a stage where no task ends fails."""
    import time

    pytest.importorskip("distributed")
    from engine.core.errors import DeepCError
    from engine.run.distributed.dask_executor import DaskExecutor

    with DaskExecutor(workers=2, stall_timeout=60) as executor:
        alive = []
        jobs = [0.05] * 120  # about 3 s on two workers: several polls
        executor.map(time.sleep, jobs, lambda k, r: alive.append(executor.client.sync(_asyncio_tasks)))
        assert len(alive) == len(jobs) and max(alive) < 2 * len(jobs) + 40  # a waiter and its wait per task
        executor.stall_timeout = 1.0
        with pytest.raises(DeepCError, match="no task ended in 1 s"):
            executor.map(time.sleep, [4.0])
