"""A run's recording stays within its budget (workbench/rerun/budget.py): whole maps of every iteration when they
fit, then maps downscaled by whole steps, then every k-th iteration; a pass that converges early still has its
last iteration recorded."""

from __future__ import annotations

import numpy as np
import pytest

from engine.core.camera import Camera
from engine.core.observer import IterationEvent
from engine.patchmatch import PatchMatchOptions
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.scene import load_scene
from tests.conftest import SAMPLES
from workbench.rerun.budget import budget_plan, logged_iterations, planned_bytes
from workbench.rerun.options import StreamOptions
from workbench.rerun.recording import Recording
from workbench.rerun.run_recording import open_run_recording, recording_plan
from workbench.rerun.stream import RerunStream, entity_name

SMALL = [(320, 240)] * 8  # sample_scenes/small, the demo


def test_logged_iterations_keep_every_kth_and_the_last_of_each_pass():
    assert logged_iterations([3, 2, 2], 1) == 7
    assert logged_iterations([3, 2, 2], 2) == 6  # {0, 2}, {0, 1}, {0, 1}
    assert logged_iterations([8, 8, 8], 4) == 9  # {0, 4, 7} per pass


def test_the_plan_prefers_whole_maps_then_half_size_then_fewer_iterations():
    assert budget_plan(SMALL, 3, [3, 2, 2], 0, 100_000) == (0, 1)  # no budget
    assert budget_plan(SMALL, 3, [3, 2, 2], 1000, 100_000) == (0, 1)  # fits whole
    # the demo: half size (every iteration would be 17.1 MB), one photometric iteration of three left out
    assert budget_plan(SMALL, 3, [3, 2, 2], 15, 100_000) == (160, 2)
    assert budget_plan(SMALL, 3, [3, 2, 2], 18, 100_000) == (160, 1)
    size, every = budget_plan(SMALL, 3, [8, 8, 8], 15, 100_000)  # the paper's schedule: also thinned
    assert size == 160 and every > 1
    assert planned_bytes(SMALL, 3, logged_iterations([8, 8, 8], every), size, 100_000) <= 15e6
    assert budget_plan(SMALL, 3, [3, 2, 2], 15, 100_000, max_size=0)[0] == 0  # given: kept
    assert budget_plan(SMALL, 3, [3, 2, 2], 15, 100_000, max_size=0, every=1) == (0, 1)
    assert budget_plan(SMALL, 3, [3, 2, 2], 0.001, 100_000) == (20, 8)  # nothing fits: the smallest plan


def _event(view: int, iteration: int, step: int, value: float) -> IterationEvent:
    depth = np.full((12, 16), value, np.float32)
    normal = np.zeros((12, 16, 3), np.float32)
    normal[..., 2] = -1
    return IterationEvent(view, "a.png", 0, "photometric", 0, iteration, step, depth, normal,
                          np.zeros((12, 16), np.float32), np.zeros((12, 16), np.uint32), 0.01)


def test_a_pass_that_converges_early_has_its_last_iteration_recorded(tmp_path):
    """Thinned to every 3rd iteration of passes planned at 8, a pass that converges after 5 iterations (0-4) still
    shows its final maps: iteration 4 is logged when the engine reports the convergence."""
    recording = Recording(tmp_path / "run.rrd")
    cam = Camera.from_params(16, 12, 20.0, 20.0, 8.0, 6.0)
    stream = RerunStream(recording.rec, [("a.png", cam, np.zeros((12, 16, 3), np.float32), [])],
                         options=StreamOptions(every=3), pass_iterations=lambda p: 8)
    stream.set_depth_ranges([(1.0, 10.0)])
    for t in range(5):
        stream.on_iteration(_event(0, t, t, 1.0 + t))
    stream.on_stage("patchmatch_view_converged", view=0, view_name="a.png", level=0, pass_index=0, iterations=5,
                    planned=8)
    recording.finish()
    from rerun.chunk import RrdReader

    base = entity_name(0, "a.png")
    table = RrdReader(str(tmp_path / "run.rrd")).stream().collect().reader(
        index="view_iteration", contents=f"/maps/{base}/depth").to_arrow_table()
    assert table["view_iteration"].to_pylist() == [0, 3, 4]
    assert f"/maps/{base}/selected_views" in str(RrdReader(str(tmp_path / "run.rrd")).stream().collect().summary())


@pytest.mark.slow
def test_a_run_recording_stays_within_its_budget(tmp_path):
    """sample_scenes/tiny under ACMM's schedule with a 5 MB budget (whole maps: 7 MB): its maps are halved, every
    iteration is kept, and the file fits."""
    scene = load_scene(SAMPLES / "tiny")
    options = PipelineOptions(patchmatch=PatchMatchOptions(schedule="acmm"))
    stream_options = StreamOptions(budget_mb=5)
    plan = recording_plan(scene, options, stream_options)
    assert (plan.max_size, plan.every) == (80, 1)
    recording = open_run_recording(str(tmp_path / "run.rrd"), scene, options, stream_options)
    run_pipeline(scene, tmp_path / "out", options, observer=recording.stream)
    recording.finish()
    size = (tmp_path / "run.rrd").stat().st_size
    assert size <= 5e6, size
    assert recording.stream.options.max_size == 80
