"""Tracing pixels from stored pass-start states, updating only the pixels the traced ones depend on.

What one half-step at pixel p reads (``kernels.half_step_kernel``), and so how far a pixel's dependencies reach:

* the other colour's hypotheses, stored costs, versions (row cache) and change flags (active set) at the
  sampling pattern's offsets (``propagation.sampling_pattern``: up to 13 px along the axes for 'deepc', 23 for
  'deepc_far' and 'acmm'), and the selected views of the 4-neighbours (the view-selection prior, 1 px);
* its own cost caches (reset by ``init_cost`` at a pass's start from its own hypothesis: local);
* the reference image's window around p and the source images and, in geometric passes, the source views' depth
  maps of the pass history: all fixed during a pass, so they add no dependency on other pixels' state;
* random numbers ``combine(key, y * W + x)`` (``rng.py``): a function of the pixel's full-level coordinates and
  the half-step only.

So after k half-steps of a pass, pixel p depends on the pass's start state within k · reach pixels (Chebyshev),
and within k · reach_l1 in L1 distance (each read moves along a pattern offset or to a 4-neighbour: for the
'deepc' patterns, samples on the axes, a diamond of half the square's pixels), and nothing else of the pass. Of
the pass's K = 2T half-steps (T: its iterations), the j-th need only be right within (K - j) · reach of the
traced pixels, since the K - j half-steps after it read no farther: by induction,
if every pixel within (K - j + 1) · reach is right before it, every pixel it updates within (K - j) · reach reads
only right values, and the other colour's are unchanged. So the pass's initial cost covers a box of radius
K · reach and its j-th half-step one of radius (K - j) · reach (the last: the traced pixels alone), about a third
of the work of one box of radius K · reach throughout, and the traced pixels get bit for bit what the whole-level
pass gives them (a bound: in practice a change travels only as far as it keeps winning, and the tests' traces
stay the same with half that radius, so the tests cannot show that the bound is tight). The box is applied
inside the kernels (``KernelParams.box_*``), with every map kept at full level size, so coordinates, random
streams and ray directions are the full level's. Tracing one pixel, each box is cut to its diamond
(``KernelParams.box_r``; the same induction in L1 distance).

What is whole-view, and so needs the stored states rather than a band from scratch: a pass's length (the
convergence test counts the whole level's changed pixels: the first replay records how many iterations each pass
ran), whether the fine window is used at all in a pass (``context.reference_terms``: any pixel of the view in the
edge band), and a level's start (JBU upsampling of the coarser level's end reaches ``jbu_radius`` coarse pixels,
but the coarser level's passes reach 2T · reach coarse pixels again: over a whole schedule the cone covers the
view, see :func:`schedule_cone`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.multiscale import PatchMatchView, effective_levels, run_view_pass, view_pyramids
from engine.patchmatch.options import PatchMatchOptions
from engine.patchmatch.probe.pixel_probe import PixelProbe, level_pixel
from engine.patchmatch.propagation import sampling_pattern
from engine.patchmatch.pyramid import level_size
from engine.patchmatch.state import ViewState

# states[(level, pass)] -> (depth (H, W) f32, normal (H, W, 3) f32) the pass started from
StartStates = dict[tuple[int, Any], tuple[np.ndarray, np.ndarray]]
# snapshots(level, pass_index, view indices) -> {view index: depth map the geometric pass read}
SnapshotFn = Callable[[int, int, list[int]], dict[int, np.ndarray]]


def pattern_reach(options: PatchMatchOptions) -> int:
    """Pixels (Chebyshev) one half-step reads around a pixel: the farthest sample of the sampling pattern, and
    at least the 4-neighbours of the view-selection prior."""
    offsets, _ = sampling_pattern(options.pattern)
    return max(1, int(np.abs(offsets).max()))


def pattern_reach_l1(options: PatchMatchOptions) -> int:
    """Pixels (L1 distance) one half-step reads around a pixel: the sampling pattern's largest |dx| + |dy|, and
    at least 1 (the 4-neighbours)."""
    offsets, _ = sampling_pattern(options.pattern)
    return max(1, int(np.abs(offsets).sum(axis=1).max()))


def dependency_region(points: list[tuple[int, int]], half_steps: int, reach: int, reach_l1: int, width: int,
                      height: int) -> tuple[int, ...]:
    """The pixels ``points`` depend on over ``half_steps`` half-steps (:func:`dependency_box`), as
    ``KernelParams``' box: (x0, y0, x1, y1), and for a single point also (x, y, r), the diamond of L1 radius
    ``half_steps * reach_l1`` around it (``reach_l1``: :func:`pattern_reach_l1`). A pattern of samples along the
    axes reaches a diamond, half the box's pixels."""
    box = dependency_box(points, half_steps, reach, width, height)
    if len(points) != 1:
        return box
    return (*box, points[0][0], points[0][1], half_steps * reach_l1)


def dependency_box(points: list[tuple[int, int]], half_steps: int, reach: int, width: int, height: int
                   ) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): the pixels of a (width, height) level that ``points`` ((x, y) at that level) depend on
    over ``half_steps`` half-steps of a pass (``reach`` px each), clipped to the level."""
    r = half_steps * reach
    xs = [p[0] for p in points]
    ys = [p[1] for p in points]
    return max(0, min(xs) - r), max(0, min(ys) - r), min(width, max(xs) + r + 1), min(height, max(ys) + r + 1)


def schedule_cone(options: PatchMatchOptions, width: int, height: int, n_levels: int,
                  iterations: Callable[[int, int], int] | None = None) -> list[dict[str, Any]]:
    """Per level (finest first), the radius in that level's pixels of the start state a pixel's whole trace
    depends on when replayed from scratch, against the level's size: ``{"level", "width", "height",
    "radius", "share"}`` (share: the fraction of the level's pixels in the box of that radius around a central
    pixel, 1 = the whole level). ``iterations(level, pass)`` defaults to the schedule's (an upper bound with
    convergence)."""
    iterations = iterations or (lambda _level, p: options.pass_iterations(p))
    reach = pattern_reach(options)
    out: list[dict[str, Any]] = []
    radius = 0.0
    for level in range(n_levels):
        if level > 0:  # the finer level's start: JBU of this level's end over jbu_radius coarse pixels
            radius = radius / 2 + options.jbu_radius + 1
        radius += sum(2 * iterations(level, p) * reach for p in range(1 + options.geom_passes))
        w, h = level_size(width, height, level)
        side = 2 * radius + 1
        out.append({"level": level, "width": w, "height": h, "radius": int(radius),
                    "share": min(1.0, side / w) * min(1.0, side / h)})
    return out


def trace_from_states(views: list[PatchMatchView], view: int, states: StartStates,
                      iterations: dict[tuple[int, int], int], snapshots: SnapshotFn, options: PatchMatchOptions,
                      probe: PixelProbe, pyramids: tuple[list, list] | None = None, regions: dict | None = None
                      ) -> None:
    """Trace ``probe``'s pixels of view ``view`` through every level and pass from ``states`` (the view's state
    at the start of every pass, from a full replay) and ``iterations`` (how many each pass ran there), updating
    only the :func:`dependency_box` of the probed pixels in each pass: the traces are those of the full replay,
    entry for entry (module doc). ``snapshots``: the source depth maps of the geometric passes
    (``engine.run.pass_history``). ``pyramids`` (images, cameras): the views' pyramids
    (``multiscale.view_pyramids``), if already made; ``regions``: the passes' fine-window regions kept between
    traces of this view (``multiscale.run_view_pass``)."""
    n_levels = effective_levels(views, options)
    v = views[view]
    if pyramids is None:
        needed = {view, *v.source_views}
        pyramids = view_pyramids([u if j in needed else None for j, u in enumerate(views)], n_levels)
    images, cameras = pyramids
    probe.bind([u.name for u in views], [(u.camera.width, u.camera.height) for u in views],
               [list(u.source_views) for u in views])
    reach, reach_l1 = pattern_reach(options), pattern_reach_l1(options)
    W, H = v.camera.width, v.camera.height
    pool = BufferPool()
    done = 0
    for level in range(n_levels - 1, -1, -1):
        pool.clear()
        lw, lh = level_size(W, H, level)
        points = sorted({level_pixel(x, y, W, H, lw, lh) for x, y in probe.pixels})
        for pass_index in range(1 + options.geom_passes):
            depth, normal = states[(level, pass_index)]
            st = ViewState(depth.copy(), normal.copy(), np.zeros((lh, lw), np.float32),
                           np.zeros((lh, lw), np.uint32))
            n_iter = iterations[(level, pass_index)]
            snapshot = None
            if pass_index > 0:
                got = snapshots(level, pass_index, list(v.source_views))
                snapshot = [got.get(j) for j in range(len(views))]
            # the pass's j-th half-step only needs to be right where the remaining 2 n_iter - j can still reach
            run_view_pass(views, view, st, images, cameras, snapshot, level, pass_index, n_levels, options, done,
                          probe, pool, iterations=n_iter, regions=regions,
                          box=lambda j, n=2 * n_iter, p=points, w=lw, h=lh: dependency_region(p, n - j, reach,
                                                                                               reach_l1, w, h))
            done += options.pass_iterations(pass_index)
