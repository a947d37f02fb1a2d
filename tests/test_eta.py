"""The whole-run ETA (engine/run/eta.py) as pure functions of the pass plan and timings, and in the progress line."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

from engine.core.camera import Camera
from engine.patchmatch import PatchMatchOptions
from engine.run.eta import (
    PlannedPass,
    RunEta,
    eta_seconds,
    format_minutes,
    pass_plan,
    pass_weight,
    units_left,
)
from workbench.cli.progress import PassProgress


def _view(w: int, h: int, sources: list[int]) -> SimpleNamespace:
    return SimpleNamespace(camera=Camera.from_params(w, h, 100.0, 100.0, w / 2, h / 2), source_views=sources,
                           depth_min=1.0, depth_max=5.0)


def test_the_plan_has_every_level_and_pass_with_each_views_pixels() -> None:
    views = [_view(320, 240, [1]), _view(320, 240, [0]), _view(320, 240, [])]  # the third has no source: skipped
    plan = pass_plan(views, PatchMatchOptions(schedule="acmm", levels=3, geom_passes=2), weights={})
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


def test_a_view_pass_that_converged_counts_at_its_plan() -> None:
    """The weights are per planned pixel-iteration (what convergence saves is in them): a view pass that ended
    after 2 of its 4 planned iterations counts as its 4, so the time it took sets the rate of the plan."""
    plan = [PlannedPass(1, 0, (100, 100), 4), PlannedPass(0, 0, (400, 400), 4)]
    now = [0.0]
    eta = RunEta(plan, 0.0, clock=lambda: now[0])
    depth = np.zeros((10, 10), np.float32)
    eta.on_stage("patchmatch_pass", level=1, pass_index=0, iterations=4)
    for t in range(2):  # view 0 stops after 2 of its 4 iterations: 1 s per iteration
        now[0] += 1.0
        eta.on_iteration(SimpleNamespace(view=0, iteration=t, depth=depth))
    assert eta.units_done == 200  # running: its iterations so far
    assert eta.seconds_left() == pytest.approx((200 + 400 + 3200) / 100)
    now[0] += 1.0
    eta.on_iteration(SimpleNamespace(view=1, iteration=0, depth=depth))  # view 0's pass is finished
    assert eta.units_done == 400 + 100  # view 0 at its plan, view 1's first iteration
    assert eta.seconds_left() == pytest.approx(3.0 / 500 * (300 + 3200))
    assert eta_seconds(plan, 0, 1, 1, 500, 3.0, 0.0) == eta.seconds_left()


def _timeline(plan: list[PlannedPass], seconds_per_unit: dict[tuple[int, int], float]) -> tuple[list, float]:
    """A synthetic run of ``plan``: every view runs its planned iterations, a pixel-iteration of pass (level,
    pass_index) takes ``seconds_per_unit`` of it; the events with their times, and the run's end."""
    events, t = [], 0.0
    for p in plan:
        events.append((t, "pass", p))
        for view, pixels in enumerate(p.view_pixels):
            for it in range(p.iterations):
                t += pixels * seconds_per_unit[(p.level, p.pass_index)]
                events.append((t, "iteration", SimpleNamespace(view=view, iteration=it,
                                                               depth=np.zeros(pixels, np.float32))))
    return events, t


def _eta_after_level(plan: list[PlannedPass], events: list, level: int) -> float:
    """RunEta's seconds left when the passes of ``level`` are done (the next pass about to start)."""
    now = [0.0]
    eta = RunEta(plan, 0.0, clock=lambda: now[0])
    for t, kind, what in events:
        now[0] = t
        if kind == "pass":
            if what.level < level:
                return eta.seconds_left()
            eta.on_stage("patchmatch_pass", level=what.level, pass_index=what.pass_index)
        else:
            eta.on_iteration(what)
    raise AssertionError("no pass after the level")


def test_per_level_and_pass_costs_weigh_what_is_left() -> None:
    """A coarse level that costs 2x per pixel-iteration and geometric passes 1.5x: the plain pixel-iteration
    count (the ETA before the weights) extrapolates the coarse level's rate over the finer ones, 100 % long after
    the first level here; with the run's cost ratios as weights it is exact."""
    views = [_view(64, 48, [1]), _view(64, 48, [0])]
    options = PatchMatchOptions(schedule="acmm", levels=2, geom_passes=1)
    cost = {(1, 0): 2.0e-3, (1, 1): 3.0e-3, (0, 0): 1.0e-3, (0, 1): 1.5e-3}  # s per pixel-iteration
    plain = pass_plan(views, options, weights={})
    events, end = _timeline(plain, cost)
    after_first = next(t for t, kind, p in events if kind == "pass" and p.level == 0)
    actual = end - after_first
    assert _eta_after_level(plain, events, 1) / actual - 1 == pytest.approx(1.0)
    weights = {(lv, "geometric" if p else "photometric"): c / cost[(0, 0)] for (lv, p), c in cost.items()}
    weighted = pass_plan(views, options, weights=weights)
    assert [p.weight for p in weighted] == [2.0, 3.0, 1.0, 1.5]
    assert _eta_after_level(weighted, events, 1) == pytest.approx(actual)


def test_pass_weights_take_the_coarsest_entry_beyond_the_table() -> None:
    weights = {(0, "photometric"): 1.0, (1, "photometric"): 2.0, (0, "geometric"): 3.0}
    assert pass_weight(0, 0, weights) == 1.0 and pass_weight(1, 0, weights) == 2.0
    assert pass_weight(4, 0, weights) == 2.0  # coarser than the table: its coarsest level
    assert pass_weight(2, 1, weights) == pass_weight(0, 2, weights) == 3.0  # every geometric pass alike
    assert pass_weight(3, 1, {}) == 1.0  # no table: every pixel-iteration alike
