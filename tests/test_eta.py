"""The whole-run ETA (engine/run/eta.py) as pure functions of the pass plan and timings, and in the progress line."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

from engine.core.camera import Camera
from engine.patchmatch import PatchMatchOptions
from engine.run.eta import PlannedPass, RunEta, eta_seconds, format_minutes, pass_plan, units_left
from workbench.cli.progress import PassProgress


def _view(w: int, h: int, sources: list[int]) -> SimpleNamespace:
    return SimpleNamespace(camera=Camera.from_params(w, h, 100.0, 100.0, w / 2, h / 2), source_views=sources,
                           depth_min=1.0, depth_max=5.0)


def test_the_plan_has_every_level_and_pass_with_each_views_pixels() -> None:
    views = [_view(320, 240, [1]), _view(320, 240, [0]), _view(320, 240, [])]  # the third has no source: skipped
    plan = pass_plan(views, PatchMatchOptions(schedule="acmm", levels=3, geom_passes=2))
    assert [(p.level, p.pass_index, p.iterations) for p in plan] == [
        (2, 0, 3), (2, 1, 2), (2, 2, 2), (1, 0, 3), (1, 1, 2), (1, 2, 2), (0, 0, 3), (0, 1, 2), (0, 2, 2)]
    assert plan[0].view_pixels == (80 * 60, 80 * 60, 0) and plan[-1].view_pixels == (320 * 240, 320 * 240, 0)
    assert plan[-1].units == 2 * 320 * 240 * 2
    # the example: the first pass is a small share of the run
    assert plan[0].units / sum(p.units for p in plan) < 0.05


def test_eta_extrapolates_the_seconds_per_pixel_iteration_over_what_is_left() -> None:
    plan = [PlannedPass(1, 0, (100, 100), 3), PlannedPass(0, 0, (400, 400), 2)]
    total = 2 * 100 * 3 + 2 * 400 * 2  # 2200 pixel-iterations
    # view 0 of the first pass done (3 iterations of 100 px) in 3 s: 1 s per 100 pixel-iterations
    assert units_left(plan, 0, 0, 3) == total - 300
    assert eta_seconds(plan, 0, 0, 3, 300, 3.0, 0.0) == pytest.approx((total - 300) / 100)
    # a view in the middle of its pass: its own iterations left count too
    assert units_left(plan, 1, 0, 1) == 400 * 1 + 400 * 2
    # the later stages' allowance: a share of PatchMatch's whole (estimated) time
    assert eta_seconds(plan, 0, 0, 3, 300, 3.0, 0.5) == pytest.approx((total - 300) / 100 + 0.5 * total / 100)
    assert eta_seconds(plan, 0, 0, 0, 0, 0.0, 0.1) is None  # nothing timed yet
    assert units_left(plan, 1, 1, 2) == 0  # the last iteration of the last view


def test_run_eta_follows_the_engines_events_and_announces_the_calibration() -> None:
    plan = [PlannedPass(1, 0, (100, 100), 2), PlannedPass(1, 1, (100, 100), 2), PlannedPass(0, 0, (400, 400), 2)]
    now = [0.0]
    announced: list[float] = []
    eta = RunEta(plan, 0.0, on_first_view=announced.append, clock=lambda: now[0])
    assert eta.seconds_left() is None and eta.text() == ""
    depth = np.zeros((10, 10), np.float32)
    eta.on_stage("patchmatch_pass", level=1, pass_index=0, iterations=2)
    for t in range(2):
        now[0] += 1.0  # 1 s per iteration of 100 px
        eta.on_iteration(SimpleNamespace(view=0, iteration=t, depth=depth))
    assert eta.seconds_left() == pytest.approx((200 + 400 + 1600) / 100)
    assert announced == []  # view 0 is finished only once the next one starts
    eta.on_iteration(SimpleNamespace(view=1, iteration=0, depth=depth))
    assert len(announced) == 1
    assert eta.text() == "ETA 14 s"  # 2100 pixel-iterations left at 2 s per 300
    # a view that converged after 1 of 2 iterations: its second one is no longer counted once the next pass starts
    now[0] += 1.0
    eta.on_stage("patchmatch_pass", level=0, pass_index=0, iterations=2)
    left = eta.seconds_left()
    # 300 pixel-iterations in 3 s; the finished view passes ran 3 of their 4 planned iterations
    assert left == pytest.approx(0.75 * 1600 * 3.0 / 300)
    eta.on_stage("patchmatch_done")
    assert eta.seconds_left() == 0.0  # no later stage allowance here


def test_format_minutes() -> None:
    assert format_minutes(12) == "12 s"
    assert format_minutes(12 * 60 + 10) == "12 min"
    assert format_minutes(3 * 3600) == "3.0 h"


def test_the_progress_line_shows_the_runs_eta(capsys) -> None:
    progress = PassProgress(eta=SimpleNamespace(text=lambda: "ETA 12 min"))
    progress("level 2 photometric", 0, 7)
    progress("level 2 photometric", 1, 7)
    progress.note("estimated 12 min on this machine")
    progress.close()
    err = capsys.readouterr().err
    assert re.search(r"level 2 photometric *: +14%.*1/7 \[\d\d:\d\d, run ETA 12 min\]", err), err
    assert "estimated 12 min on this machine" in err


def test_what_is_left_is_counted_at_the_share_of_the_plan_finished_view_passes_ran() -> None:
    """A view pass that ends by convergence (2 of 4 planned iterations) halves the estimate of what is left."""
    plan = [PlannedPass(1, 0, (100, 100), 4), PlannedPass(0, 0, (400, 400), 4)]
    now = [0.0]
    eta = RunEta(plan, 0.0, clock=lambda: now[0])
    depth = np.zeros((10, 10), np.float32)
    eta.on_stage("patchmatch_pass", level=1, pass_index=0, iterations=4)
    for t in range(2):  # view 0 stops after 2 of its 4 iterations: 1 s per 100 px
        now[0] += 1.0
        eta.on_iteration(SimpleNamespace(view=0, iteration=t, depth=depth))
    assert eta.run_share == 1.0  # nothing finished yet: the plan as it is
    assert eta.seconds_left() == pytest.approx((200 + 400 + 3200) / 100)
    now[0] += 1.0
    eta.on_iteration(SimpleNamespace(view=1, iteration=0, depth=depth))  # view 0's pass is finished
    assert eta.run_share == pytest.approx(0.5)
    assert eta.seconds_left() == pytest.approx(0.5 * (300 + 3200) / 100)
    assert eta_seconds(plan, 0, 1, 1, 300, 3.0, 0.0, run_share=0.5) == eta.seconds_left()
