"""A whole-run time estimate: PatchMatch's work as weighted pixel-iterations over every level and pass, timed as it
runs.

A pass's progress alone misleads ("level 2 photometric 1/7 [08:17<49:46]" is one of nine passes at a sixteenth
of the pixels). :func:`pass_plan` lists every pass with each view's pixels at its level, the pass's planned
iterations and the cost weight of one of its pixel-iterations (:data:`PASS_WEIGHTS`); :func:`eta_seconds`
extrapolates the wall seconds per weighted pixel-iteration measured so far over what is left, plus a rough
allowance for the stages after PatchMatch (``LATER_SHARE``). :class:`RunEta` follows a run's observer events and
gives the estimate at any moment.

The model: a pass's wall time is its planned pixel-iterations times its weight times one machine factor (wall
seconds per weighted pixel-iteration, measured from the run so far, so a slower or busier machine is followed).
A weight is per *planned* pixel-iteration, so a finished view pass counts at its plan whatever iteration
convergence ended it at: what convergence saves is part of the weight. Measured on the 7-frame video at 640x360
(benchmarks/performance/eta_costs.py, benchmarks/reliability/first_try.py; numbers and sources in
docs/decisions.md "Whole-run ETA"): per CPU second the passes cost alike (0.97-1.35x the finest photometric pass
per planned pixel-iteration, the same in two runs), but per wall second the coarsest level cost 2.2x and the finest
geometric passes 1.75x on a machine with a core to spare (the finest photometric pass uses both cores, the coarse
levels barely gain from a second), and 0.85-3.1x in runs beside other jobs (load 7), as the load came and went.
:data:`PASS_WEIGHTS` is the geometric mean of two runs' wall ratios; replayed on three runs the ETA after the first
level was within -47 % .. +8 % (every pixel-iteration alike: -21 % .. +61 %). It stays rough: it extrapolates the
load so far.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

from engine.patchmatch import PatchMatchOptions
from engine.patchmatch.multiscale import PatchMatchView, effective_levels
from engine.patchmatch.pyramid import level_size

# the stages after PatchMatch (counter maps, confidence, refinement, fusion, evaluation) as a share of
# PatchMatch's time, per pipeline: tests/baselines' metrics of tiny, small and fountain_p11 (vanilla 1-4 %,
# fast 5-8 %, full about 100 %: the refinement), rounded up
LATER_SHARE = {"vanilla": 0.05, "fast": 0.1, "full": 1.0}


# Cost of a planned pixel-iteration by (level, pass kind), relative to one of the finest level's photometric pass
# (level 0 = the finest; a level coarser than the table's coarsest takes its weight): wall-second ratios of two whole
# default runs of a 7-frame video at 640x360 on 2 cores, their geometric mean (docs/decisions.md "Whole-run ETA").
# A weight holds what a pass costs beyond its pixel-iterations: per-view work that does not shrink with the pixels
# at the coarse levels, the geometric term, the active set, the iterations convergence saves, and how much a level
# gains from a second core (the finest levels' kernels use every thread, the coarse levels barely gain).
PASS_WEIGHTS: dict[tuple[int, str], float] = {(0, "photometric"): 1.0, (0, "geometric"): 1.85,
                                              (1, "photometric"): 1.38, (1, "geometric"): 1.04,
                                              (2, "photometric"): 2.61, (2, "geometric"): 2.03}


def pass_weight(level: int, pass_index: int, weights: dict[tuple[int, str], float] | None = None) -> float:
    """The cost weight of a planned pixel-iteration of pass ``pass_index`` at ``level`` in ``weights`` (default
    :data:`PASS_WEIGHTS`; 1 when the table is empty)."""
    table = PASS_WEIGHTS if weights is None else weights
    kind = "geometric" if pass_index > 0 else "photometric"
    coarsest = max((lv for lv, k in table if k == kind), default=None)
    if coarsest is None:
        return 1.0
    return table.get((min(level, coarsest), kind), table[(coarsest, kind)])


@dataclasses.dataclass(frozen=True)
class PlannedPass:
    """One PatchMatch pass over all views: ``view_pixels`` per view at its level (0 for a view PatchMatch skips),
    its planned (maximum) red-black iterations and the cost ``weight`` of one of its pixel-iterations
    (:data:`PASS_WEIGHTS`)."""

    level: int
    pass_index: int
    view_pixels: tuple[int, ...]
    iterations: int
    weight: float = 1.0

    @property
    def units(self) -> int:
        """Pixel-iterations of the whole pass."""
        return sum(self.view_pixels) * self.iterations

    @property
    def cost(self) -> float:
        """Weighted pixel-iterations of the whole pass (``units`` x ``weight``)."""
        return self.units * self.weight


def pass_plan(views: Sequence[PatchMatchView], options: PatchMatchOptions,
              weights: dict[tuple[int, str], float] | None = None) -> list[PlannedPass]:
    """Every pass ``engine.patchmatch.run_patchmatch`` runs on ``views``, in its order (coarsest level first), each
    with its cost weight (``weights``, default :data:`PASS_WEIGHTS`; ``{}`` weighs every pixel-iteration alike)."""
    n_levels = effective_levels(list(views), options)
    active = [bool(v.source_views) and 0.0 < float(v.depth_min) < float(v.depth_max) for v in views]
    plan = []
    for level in range(n_levels - 1, -1, -1):
        sizes = [level_size(v.camera.width, v.camera.height, level) for v in views]
        pixels = tuple(w * h if ok else 0 for (w, h), ok in zip(sizes, active, strict=True))
        for pass_index in range(1 + options.geom_passes):
            plan.append(PlannedPass(level, pass_index, pixels, options.pass_iterations(pass_index),
                                    pass_weight(level, pass_index, weights)))
    return plan


def units_left(plan: Sequence[PlannedPass], current: int, view: int, iterations_done: int) -> float:
    """Weighted pixel-iterations still to run when view ``view`` of pass ``plan[current]`` has run
    ``iterations_done`` iterations (the views after it and the passes after it at their planned iterations)."""
    p = plan[current]
    left = p.view_pixels[view] * max(p.iterations - iterations_done, 0)
    left += sum(p.view_pixels[view + 1:]) * p.iterations
    return left * p.weight + sum(q.cost for q in plan[current + 1:])


def eta_seconds(plan: Sequence[PlannedPass], current: int, view: int, iterations_done: int, units_done: float,
                elapsed: float, later_share: float) -> float | None:
    """Seconds left to the end of the run: PatchMatch's weighted pixel-iterations left at the wall seconds per
    weighted pixel-iteration so far (``elapsed`` over the weighted ``units_done`` this process ran), plus
    ``later_share`` of PatchMatch's whole time for the later stages; None before anything was timed."""
    if units_done <= 0 or elapsed <= 0:
        return None
    rate = elapsed / units_done
    return rate * units_left(plan, current, view, iterations_done) + later_share * rate * sum(q.cost for q in plan)


def format_minutes(seconds: float) -> str:
    """'ETA'-style duration: '40 s' under a minute, else whole minutes ('12 min'), hours past 90 minutes."""
    if seconds < 60:
        return f"{max(seconds, 1):.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


class RunEta:
    """An engine observer (``engine.core.observer``) that times PatchMatch's pixel-iterations and answers
    :meth:`seconds_left` at any moment (thread-safe enough for a reader thread: it reads a few numbers).

    ``on_first_view(seconds)`` is called once the first view pass has been timed
    (the calibration: ``deepc run`` prints "estimated N min on this machine")."""

    def __init__(self, plan: list[PlannedPass], later_share: float,
                 on_first_view: Callable[[float], Any] | None = None, clock: Callable[[], float] = time.monotonic):
        self.plan, self.later_share = plan, later_share
        self.on_first_view, self.clock = on_first_view, clock
        self._index = {(p.level, p.pass_index): k for k, p in enumerate(plan)}
        self.current = 0
        self.view = 0
        self.iterations_done = 0
        # weighted pixel-iterations done: a finished view pass counts at its plan (the weights are per planned
        # pixel-iteration: what convergence saves is in them), the view running at the iterations it has run
        self.units_done = 0.0
        self.started: float | None = None
        self.patchmatch_done: float | None = None
        self._announced = False
        self._view_pixels = 0

    def on_stage(self, name: str, **info: Any) -> None:
        if name == "patchmatch_pass":
            self._view_finished()
            self.current = self._index.get((info.get("level"), info.get("pass_index")), self.current)
            self.view = self.iterations_done = 0
            if self.started is None:
                self.started = self.clock()
        elif name == "patchmatch_done" and self.started is not None:
            self.patchmatch_done = self.clock()

    def on_iteration(self, event: Any) -> None:
        if event.view != self.view:
            self._view_finished()
        self.view, self.iterations_done = event.view, event.iteration + 1
        self._view_pixels = int(event.depth.size)
        self.units_done += self._view_pixels * self.plan[self.current].weight

    def _view_finished(self) -> None:
        """The view that ran last has finished its pass: the iterations its plan had left (it ended by
        convergence) count as done, and the first time, the calibration is announced."""
        if self._view_pixels:
            p = self.plan[self.current]
            self.units_done += self._view_pixels * max(p.iterations - self.iterations_done, 0) * p.weight
            self._view_pixels = 0
        if not self._announced and self.on_first_view is not None and self.units_done:
            self._announced = True
            seconds = self.seconds_left()
            if seconds is not None:
                self.on_first_view(seconds)

    def seconds_left(self) -> float | None:
        """Seconds to the end of the run from now (None before the first iteration is timed)."""
        if self.started is None:
            return None
        now = self.clock()
        if self.patchmatch_done is not None:  # the later stages: their allowance less the time they have run
            pm = self.patchmatch_done - self.started
            return max(self.later_share * pm - (now - self.patchmatch_done), 0.0)
        return eta_seconds(self.plan, self.current, self.view, self.iterations_done, self.units_done,
                           now - self.started, self.later_share)

    def text(self) -> str:
        """'ETA 12 min', '' before anything was timed."""
        seconds = self.seconds_left()
        return "" if seconds is None else f"ETA {format_minutes(seconds)}"
