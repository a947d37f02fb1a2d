"""When a PatchMatch pass has stopped gaining, and which passes ended early.

Red-black iterations after a pass has converged mostly shuffle the same few unreliable pixels: on the sample
scene ``small`` the pooled depth within 1 % of GT stops moving after two or three iterations of every pass,
while the share of pixels changing by more than 1 % settles at 3-7 % (see
``benchmarks/experiments/patchmatch_convergence.py``). :class:`Convergence` detects that plateau;
:class:`EarlyStops` collects, for metrics.json, the passes it ended.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.patchmatch.options import PatchMatchOptions


class Convergence:
    """Whether a pass has stopped gaining: the share of pixels whose depth an iteration moves by more than
    ``options.converge_depth`` (relative) no longer falls by more than a factor ``options.converge_ratio``
    from one iteration to the next (then further iterations mostly shuffle the same unreliable pixels)."""

    def __init__(self, depth: np.ndarray, options: PatchMatchOptions):
        self.previous = depth.copy()
        self.ratio = float(options.converge_ratio)
        self.tolerance = np.float32(options.converge_depth)
        self.changed: list[float] = []  # per iteration, share of the pixels

    def update(self, depth: np.ndarray) -> bool:
        """Count the pixels the iteration just run changed; whether the pass has converged."""
        moved = np.abs(depth - self.previous) > self.tolerance * np.maximum(depth, self.previous)
        self.changed.append(float(np.count_nonzero(moved)) / depth.size)
        self.previous[:] = depth
        return len(self.changed) >= 2 and self.changed[-1] > self.ratio * self.changed[-2]


class EarlyStops:
    """An observer of ``run_patchmatch`` that keeps the view passes which ended early (stage events
    ``patchmatch_view_converged``) and sums the iterations' work (pixel updates, those the active set skipped,
    NCC windows). It sees the passes this process ran: a ``--resume`` run leaves out the restored ones."""

    def __init__(self) -> None:
        self.stops: list[dict[str, int]] = []
        self.work = {"pixel_updates": 0, "pixels_skipped": 0, "ncc_windows": 0}

    def on_iteration(self, event: Any) -> None:
        for key in self.work:
            self.work[key] += int(getattr(event, key))

    def on_stage(self, name: str, **info: Any) -> None:
        if name == "patchmatch_view_converged":
            self.stops.append({k: int(info[k]) for k in ("view", "level", "pass_index", "iterations", "planned")})

    def summary(self) -> dict[str, Any]:
        """``{"view_passes_ended_early", "iterations_saved", "by_pass": {"L<level>_P<pass>": [[view,
        iterations], ...]}, "pixel_updates", "pixels_skipped", "ncc_windows"}`` for metrics.json."""
        by_pass: dict[str, list[list[int]]] = {}
        for s in self.stops:
            by_pass.setdefault(f"L{s['level']}_P{s['pass_index']}", []).append([s["view"], s["iterations"]])
        return {"view_passes_ended_early": len(self.stops),
                "iterations_saved": sum(s["planned"] - s["iterations"] for s in self.stops), "by_pass": by_pass,
                **self.work}
