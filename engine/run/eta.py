"""A whole-run time estimate: PatchMatch's work as weighted pixel-iterations over every level and pass, timed as it
runs.

A pass's progress alone misleads ("level 2 photometric 1/7 [08:17<49:46]" is one of nine passes at a sixteenth
of the pixels). :func:`pass_plan` lists every pass with each view's pixels at its level, the pass's planned
iterations and the cost weight of one of its pixel-iterations (:data:`PASS_WEIGHTS`); :func:`eta_seconds`
extrapolates the wall seconds per weighted pixel-iteration measured so far over what is left, plus a rough
allowance for the stages after PatchMatch (``LATER_SHARE``). :class:`RunEta` follows a run's observer events and
gives the estimate at any moment.

The model: a pass's time is proportional to its planned pixel-iterations times its weight, the same machine
factor (seconds per weighted pixel-iteration, which load moves) for every pass. The weights are CPU-time ratios
measured on a whole default run, per level and pass kind (``benchmarks/performance/eta_costs.py``); a weight is per
*planned* pixel-iteration, so a finished view pass counts at its plan whatever iteration convergence ended it at:
what convergence saves, like the per-view work that does not shrink with the pixels, is part of the weight.
"""

from __future__ import annotations

import dataclasses
import os
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
# (level 0 = the finest; a level coarser than a table's coarsest takes its weight), measured on whole default runs
# of a 7-frame video at 640x360 (docs/decisions.md "Whole-run ETA"). A weight holds what a pass costs beyond its
# pixel-iterations: per-view work that does not shrink with the pixels at the coarse levels, the geometric term,
# the active set and the iterations convergence saves. The ratios depend on the cores the run gets: the finest
# levels' kernels run on every thread while the coarse levels barely gain from a second one, so with a core to
# spare the finest levels cost less against the coarse ones than on a machine other jobs keep busy. Two tables,
# and :class:`RunEta` interpolates between them (geometrically) by the spare share it measures (:class:`CpuShare`).
# BUSY_WEIGHTS: other jobs kept both cores busy (wall seconds, benchmarks/performance/eta_costs.py).
BUSY_WEIGHTS: dict[tuple[int, str], float] = {(0, "photometric"): 1.0, (0, "geometric"): 1.0,
                                              (1, "photometric"): 1.0, (1, "geometric"): 1.0,
                                              (2, "photometric"): 1.0, (2, "geometric"): 1.0}
# FREE_WEIGHTS: the run had a core to spare for most of its time (the pass ends of
# benchmarks/reliability/first_try.py's run of d9f0ea3).
FREE_WEIGHTS: dict[tuple[int, str], float] = dict(BUSY_WEIGHTS)
# the spare share assumed where it cannot be measured (no /proc/stat): a machine of one's own
DEFAULT_SPARE = 1.0


def pass_weight(level: int, pass_index: int, weights: dict[tuple[int, str], float] | None = None) -> float:
    """The cost weight of a planned pixel-iteration of pass ``pass_index`` at ``level`` in ``weights`` (default
    :data:`BUSY_WEIGHTS`; 1 when the table is empty)."""
    table = BUSY_WEIGHTS if weights is None else weights
    kind = "geometric" if pass_index > 0 else "photometric"
    coarsest = max((lv for lv, k in table if k == kind), default=None)
    if coarsest is None:
        return 1.0
    return table.get((min(level, coarsest), kind), table[(coarsest, kind)])


@dataclasses.dataclass(frozen=True)
class PlannedPass:
    """One PatchMatch pass over all views: ``view_pixels`` per view at its level (0 for a view PatchMatch skips),
    its planned (maximum) red-black iterations and the cost weight of one of its pixel-iterations on a busy
    machine (``weight``) and with a core to spare (``free_weight``; None: the same)."""

    level: int
    pass_index: int
    view_pixels: tuple[int, ...]
    iterations: int
    weight: float = 1.0
    free_weight: float | None = None

    @property
    def units(self) -> int:
        """Pixel-iterations of the whole pass."""
        return sum(self.view_pixels) * self.iterations

    def weight_at(self, spare: float = 0.0) -> float:
        """The weight at a spare share in [0, 1]: ``weight`` at 0, ``free_weight`` at 1, geometric between."""
        free = self.weight if self.free_weight is None else self.free_weight
        return self.weight ** (1.0 - spare) * free ** spare

    def cost(self, spare: float = 0.0) -> float:
        """Weighted pixel-iterations of the whole pass (``units`` x its weight at ``spare``)."""
        return self.units * self.weight_at(spare)


def pass_plan(views: Sequence[PatchMatchView], options: PatchMatchOptions,
              weights: dict[tuple[int, str], float] | None = None,
              free_weights: dict[tuple[int, str], float] | None = None) -> list[PlannedPass]:
    """Every pass ``engine.patchmatch.run_patchmatch`` runs on ``views``, in its order (coarsest level first), each
    with its cost weights: ``weights`` on a busy machine and ``free_weights`` with a core to spare (defaults
    :data:`BUSY_WEIGHTS` and :data:`FREE_WEIGHTS`; ``weights`` given alone serves both; ``{}`` weighs every
    pixel-iteration alike)."""
    if free_weights is None:
        free_weights = FREE_WEIGHTS if weights is None else weights
    n_levels = effective_levels(list(views), options)
    active = [bool(v.source_views) and 0.0 < float(v.depth_min) < float(v.depth_max) for v in views]
    plan = []
    for level in range(n_levels - 1, -1, -1):
        sizes = [level_size(v.camera.width, v.camera.height, level) for v in views]
        pixels = tuple(w * h if ok else 0 for (w, h), ok in zip(sizes, active, strict=True))
        for pass_index in range(1 + options.geom_passes):
            plan.append(PlannedPass(level, pass_index, pixels, options.pass_iterations(pass_index),
                                    pass_weight(level, pass_index, weights),
                                    pass_weight(level, pass_index, free_weights)))
    return plan


def units_left(plan: Sequence[PlannedPass], current: int, view: int, iterations_done: int,
               spare: float = 0.0) -> float:
    """Weighted pixel-iterations (at ``spare``) still to run when view ``view`` of pass ``plan[current]`` has run
    ``iterations_done`` iterations (the views after it and the passes after it at their planned iterations)."""
    p = plan[current]
    left = p.view_pixels[view] * max(p.iterations - iterations_done, 0)
    left += sum(p.view_pixels[view + 1:]) * p.iterations
    return left * p.weight_at(spare) + sum(q.cost(spare) for q in plan[current + 1:])


def eta_seconds(plan: Sequence[PlannedPass], current: int, view: int, iterations_done: int, units_done: float,
                elapsed: float, later_share: float, spare: float = 0.0) -> float | None:
    """Seconds left to the end of the run: PatchMatch's weighted pixel-iterations left at the wall seconds per
    weighted pixel-iteration so far (``elapsed`` over the weighted ``units_done`` this process ran), plus
    ``later_share`` of PatchMatch's whole time for the later stages; None before anything was timed. ``spare``:
    the weights' spare share (:meth:`PlannedPass.weight_at`)."""
    if units_done <= 0 or elapsed <= 0:
        return None
    rate = elapsed / units_done
    return (rate * units_left(plan, current, view, iterations_done, spare)
            + later_share * rate * sum(q.cost(spare) for q in plan))


class CpuShare:
    """The share of a spare core this process has had since it was made, in [0, 1]: the cores available to it
    (its own CPU seconds per wall second plus the machine's idle cores, from /proc/stat) less one, over its
    threads less one (numba's). 0: the run got one core or less (other jobs keep the machine busy); 1: it could
    have run every thread. None where /proc/stat cannot be read (not Linux) or no time has passed."""

    def __init__(self, threads: int | None = None, clock: Callable[[], float] = time.monotonic):
        if threads is None:
            import numba  # lazy: the engine's thread count

            threads = numba.get_num_threads()
        self.threads, self.clock = max(int(threads), 1), clock
        self.start = self._sample()

    @staticmethod
    def sample(clock: Callable[[], float] = time.monotonic) -> tuple[float, float, float, float] | None:
        """(wall s, this process's CPU s, idle jiffies, total jiffies of all CPUs), None without /proc/stat."""
        try:
            with open("/proc/stat") as f:
                fields = [float(x) for x in f.readline().split()[1:]]
        except (OSError, ValueError):
            return None
        if len(fields) < 5:
            return None
        return clock(), time.process_time(), fields[3] + fields[4], sum(fields[:8])

    def _sample(self) -> tuple[float, float, float, float] | None:
        return self.sample(self.clock)

    def share(self) -> float | None:
        return spare_share(self.start, self._sample(), self.threads, os.cpu_count() or 1)


def spare_share(start: Sequence[float] | None, now: Sequence[float] | None, threads: int, cpus: int) -> float | None:
    """:class:`CpuShare`'s share between two samples (:meth:`CpuShare.sample`) of a process of ``threads`` threads
    on ``cpus`` CPUs; None without both samples or without time between them."""
    if start is None or now is None or now[0] <= start[0] or now[3] <= start[3]:
        return None
    if threads <= 1:
        return 0.0
    own = (now[1] - start[1]) / (now[0] - start[0])
    idle = (now[2] - start[2]) / (now[3] - start[3]) * cpus
    return min(max((own + idle - 1.0) / (threads - 1), 0.0), 1.0)


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
    (the calibration: ``deepc run`` prints "estimated N min on this machine"). ``spare()`` gives the spare share
    the weights are taken at (None: :data:`DEFAULT_SPARE`); by default a :class:`CpuShare` made when PatchMatch
    starts measures it."""

    def __init__(self, plan: list[PlannedPass], later_share: float,
                 on_first_view: Callable[[float], Any] | None = None, clock: Callable[[], float] = time.monotonic,
                 spare: Callable[[], float | None] | None = None):
        self.plan, self.later_share = plan, later_share
        self.on_first_view, self.clock, self._spare = on_first_view, clock, spare
        self._index = {(p.level, p.pass_index): k for k, p in enumerate(plan)}
        self.current = 0
        self.view = 0
        self.iterations_done = 0
        # pixel-iterations done per pass: a finished view pass counts at its plan (the weights are per planned
        # pixel-iteration: what convergence saves is in them), the view running at the iterations it has run
        self.done = [0] * len(plan)
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
                if self._spare is None:
                    self._spare = CpuShare().share
        elif name == "patchmatch_done" and self.started is not None:
            self.patchmatch_done = self.clock()

    def on_iteration(self, event: Any) -> None:
        if event.view != self.view:
            self._view_finished()
        self.view, self.iterations_done = event.view, event.iteration + 1
        self._view_pixels = int(event.depth.size)
        self.done[self.current] += self._view_pixels

    def _view_finished(self) -> None:
        """The view that ran last has finished its pass: the iterations its plan had left (it ended by
        convergence) count as done, and the first time, the calibration is announced."""
        if self._view_pixels:
            p = self.plan[self.current]
            self.done[self.current] += self._view_pixels * max(p.iterations - self.iterations_done, 0)
            self._view_pixels = 0
        if not self._announced and self.on_first_view is not None and any(self.done):
            self._announced = True
            seconds = self.seconds_left()
            if seconds is not None:
                self.on_first_view(seconds)

    def spare(self) -> float:
        """The spare share the weights are taken at now."""
        measured = self._spare() if self._spare is not None else None
        return DEFAULT_SPARE if measured is None else measured

    def units_done(self, spare: float = 0.0) -> float:
        """Weighted pixel-iterations done (at ``spare``)."""
        return sum(n * p.weight_at(spare) for n, p in zip(self.done, self.plan, strict=True))

    def seconds_left(self) -> float | None:
        """Seconds to the end of the run from now (None before the first iteration is timed)."""
        if self.started is None:
            return None
        now = self.clock()
        if self.patchmatch_done is not None:  # the later stages: their allowance less the time they have run
            pm = self.patchmatch_done - self.started
            return max(self.later_share * pm - (now - self.patchmatch_done), 0.0)
        spare = self.spare()
        return eta_seconds(self.plan, self.current, self.view, self.iterations_done, self.units_done(spare),
                           now - self.started, self.later_share, spare)

    def text(self) -> str:
        """'ETA 12 min', '' before anything was timed."""
        seconds = self.seconds_left()
        return "" if seconds is None else f"ETA {format_minutes(seconds)}"
