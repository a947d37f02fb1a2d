"""One pass of PatchMatch over one reference view at one pyramid level: the initial cost of its hypotheses,
then red-black iterations (Xu & Tao 2019 ACMM; Kuhn et al. 2020 DeepC-MVS).

:func:`run_view_level` is the public entry point (the engine runs every view pass with it; tests and
benchmarks call it on a :class:`~engine.patchmatch.state.ViewState` and a ``context.ViewContext`` they
build). :func:`init_cost` and :func:`half_step` are its two steps, for tests that look between them. Both run their
kernel over blocks of rows (``engine.core.blocks``), so that a stop request waits a fraction of a second, not a
whole view; the maps are the same whatever the blocks.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

import engine.patchmatch.kernels as K
from engine.core.blocks import RowPacer
from engine.core.interrupt import check_interrupt
from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import ViewContext
from engine.patchmatch.convergence import Convergence
from engine.patchmatch.options import PatchMatchOptions
from engine.patchmatch.probe.pixel_probe import PassProbe
from engine.patchmatch.propagation import sampling_pattern
from engine.patchmatch.records import KernelParams, RowBlock, SamplingPattern, kernel_params
from engine.patchmatch.rng import stream_key
from engine.patchmatch.state import ViewState

RESTORER_ITERATION = (1 << 20) + 1  # stream id of the detail restorer's random reference normals

IterationFn = Callable[[int, np.ndarray, float], object]
# (x0, y0, x1, y1): the pixels [x0, x1) x [y0, y1) a kernel updates; optionally followed by (cx, cy, r): only those
# within L1 distance r of (cx, cy) (records.KernelParams)
Box = tuple[int, ...]
PACER = RowPacer()  # the row blocks of this process's kernel calls (only their time depends on it)


def perturbation_scale(options: PatchMatchOptions, iteration: int, done_before: int) -> float:
    """ε of iteration ``iteration`` of a pass preceded by ``done_before`` iterations of earlier passes
    (all levels): 2^-t per pass ('pass', Kuhn et al. 2020), or 2^-(done_before + t) floored at eps_min
    ('global')."""
    if options.eps_schedule == "pass":
        return 2.0 ** (-iteration)
    return max(2.0 ** (-(done_before + iteration)), options.eps_min)


def pattern_of(options: PatchMatchOptions) -> SamplingPattern:
    """The sampling pattern ``options.pattern`` names."""
    return SamplingPattern(*sampling_pattern(options.pattern))


def n_regions(pattern: SamplingPattern) -> int:
    """Regions of a sampling pattern (``KernelParams.n_regions``)."""
    return int(pattern.regions.max()) + 1


def init_cost(state: ViewState, ctx: ViewContext, params: KernelParams, cache: bool = True,
              pool: BufferPool | None = None, pacer: RowPacer | None = PACER) -> None:
    """Recompute cost and selected views of the stored hypotheses (ACMM's top-k initial cost); with ``cache``
    also (re)start the cost caches the half-steps of this pass read (allocated from ``pool`` if given).
    ``pacer``: the row blocks (a stop request is honoured between them); None: one call over the whole view."""
    if cache:
        state.prepare_caches(ctx.num_sources, params.k_update, True, pool)
    view_costs = state.view_costs if cache else np.empty((1, 1, 1), np.float32)
    known, known_wset = state.known_costs, state.known_window_set
    if known is None:  # the kernel also ignores carried-over costs of another shape
        known, known_wset = np.empty((1, 1, 1), np.float32), np.empty((1, 1), np.uint8)
    maps, ref, sources = state.maps(), ctx.reference_windows(), ctx.source_images()

    def block(start: int, stop: int) -> None:
        K.init_cost_kernel(maps, view_costs, cache, known, known_wset, ref, sources, params, RowBlock(start, stop))

    h, w = state.depth.shape
    if pacer is None:
        block(0, h)
    else:
        pacer.run("init_cost", h, w, block)
    state.known_costs = state.known_window_set = None  # only valid for the hypotheses they were computed for


def half_step(state: ViewState, ctx: ViewContext, colour: int, cpre: np.ndarray, pattern: SamplingPattern,
              key: np.uint64, params: KernelParams, pacer: RowPacer | None = PACER) -> np.ndarray:
    """One red (``colour`` 1) or black (0) half-step on one view (in place). Call :func:`init_cost` first in
    every pass (and after changing the state's maps from outside): it fills the cost cache the half-steps
    trust. ``cpre`` (H, W) f32: the detail restorer's reference cost (read only with
    ``params.detail_restorer``); ``key``: the half-step's random stream (``rng.stream_key``); ``pacer``: the row
    blocks (a stop request is honoured between them: the view is then left half-updated); None: one call.

    Returns (N_COUNTS,) int64: NCC windows evaluated for the view-selection rows, the current
    hypotheses, the remaining candidates and the refinement, the number of pixels updated and the number the
    active set left alone (``params.active_share``)."""
    rows = state.prepare_caches(ctx.num_sources, params.k_update, False)
    h, w = state.depth.shape
    counts = np.zeros((h, K.N_COUNTS), np.int64)
    state.clock[0] += np.uint32(1)  # this half-step's stamp, the same in all its blocks
    maps, caches, ref, sources = state.maps(), state.caches(rows), ctx.reference_windows(), ctx.source_images()

    def block(start: int, stop: int) -> None:
        K.half_step_kernel(colour, maps, caches, cpre, ref, sources, pattern, key, params, RowBlock(start, stop),
                           counts)

    if pacer is None:
        block(0, h)
    else:
        pacer.run("half_step", h, w, block)
    return counts.sum(axis=0)


def restorer_reference(state: ViewState, ctx: ViewContext, options: PatchMatchOptions, params: KernelParams,
                       view: int, level: int) -> np.ndarray | None:
    """Cpre for detail_restorer_reference='random': top-k photometric cost (ACMM's initial cost) of the
    upsampled depth with a random normal facing the camera (None for 'upsampled': computed by the caller)."""
    if options.detail_restorer_reference != "random":
        return None
    h, w = state.depth.shape
    tmp = ViewState(np.empty((h, w), np.float32), np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32),
                    np.empty((h, w), np.uint32))
    key = np.uint64(stream_key(options.seed, view, level, 0, RESTORER_ITERATION, 0))
    K.random_init_kernel(tmp.depth, tmp.normal, ctx.kinv, params.zmin, params.zmax, key, False)
    tmp.depth[:] = state.depth
    init_cost(tmp, ctx, params, cache=False)
    return tmp.cost


def run_view_level(state: ViewState, ctx: ViewContext, options: PatchMatchOptions, zmin: float, zmax: float, *,
                   view: int = 0, level: int = 0, pass_index: int = 0, detail: bool = False,
                   iterations: int | None = None, done_before: int = 0, on_iteration: IterationFn | None = None,
                   pool: BufferPool | None = None, probe: PassProbe | None = None,
                   box: Box | Callable[[int], Box] | None = None) -> np.ndarray:
    """Run one pass of PatchMatch over one reference view at one pyramid level, in place on ``state``.

    The initial cost of the stored hypotheses (ACMM's top-k rule), then ``iterations`` (default
    ``options.pass_iterations(pass_index)``) red-black iterations of a black and a red :func:`half_step`.
    Pass 0 is photometric, later passes are geometric (``ctx`` must then hold the sources' depth maps);
    ``detail`` turns the detail restorer on (ACMM; the photometric pass of a finer level, after upsampling).
    ``view``, ``level`` and ``pass_index`` name the pass's random streams (``rng.stream_key``): the same
    arguments give the same maps on any thread count. ``done_before``: iterations of all earlier passes
    (perturbation schedule 'global'). ``zmin``, ``zmax``: the view's depth range (camera z, scene units).

    ``on_iteration(t, counts, seconds)`` is called after every iteration with the (N_COUNTS,) int64 counts
    of its two half-steps (columns ``kernels.CNT_*``). A stop request (``engine.core.interrupt``) is honoured
    between iterations. The pass's caches are dropped at the end; the photometric costs of the final
    hypotheses are kept for the next pass of this level (``pass_index < options.geom_passes``).
    With ``options.converge_ratio`` > 0 (and ``iterations`` unset) the pass ends early once it has converged
    (:class:`Convergence`): the iteration after that is its last. With ``options.active_share`` >= 0 the
    iterations from ``records.ACTIVE_FROM_ITERATION`` on, except the pass's last, update only the active set
    (``kernels.half_step_kernel``).
    ``probe`` (``probe.PassProbe``): explains its pixels before each half-step and records what the kernel
    wrote (outside the kernels: the maps are the same with or without it).
    ``box`` (x0, y0, x1, y1): only the pixels [x0, x1) x [y0, y1) are costed and updated, the others keep their
    maps (the pixel probe's partial replay: a pixel depends only on pixels within the pattern's reach per
    half-step; None = all); or ``box(j)``, the box of the pass's initial cost (j = 0) and of its j-th half-step
    (j = 1, 2, ...): a box that shrinks as fewer half-steps remain to read it.
    Returns the (N_COUNTS,) int64 counts of the whole pass."""
    pattern = pattern_of(options)
    geometric = pass_index > 0
    n_iter = options.pass_iterations(pass_index) if iterations is None else iterations
    box_at = box if callable(box) else (lambda _j: box)
    params = kernel_params(options, zmin, zmax, 0, geometric, detail, n_regions(pattern), box=box_at(0))
    if probe is not None:
        probe.start(state)
    if detail:
        cpre = restorer_reference(state, ctx, options, params, view, level)
    init_cost(state, ctx, params, pool=pool)
    if not detail:
        cpre = state.cost
    elif options.detail_restorer_reference == "upsampled":
        cpre = state.cost.copy()
    total = np.zeros(K.N_COUNTS, np.int64)
    convergence = Convergence(state.depth, options) if iterations is None and options.converge_ratio > 0 else None
    last = n_iter == 1
    for t in range(n_iter):
        check_interrupt()  # a stop request is honoured between kernels (engine/core/interrupt.py)
        t0 = time.perf_counter()
        counts = np.zeros(K.N_COUNTS, np.int64)
        for colour in (0, 1):
            params = kernel_params(options, zmin, zmax, t, geometric, detail, n_regions(pattern),
                                   perturbation_scale(options, t, done_before), last=last,
                                   box=box_at(2 * t + colour + 1))
            key = np.uint64(stream_key(options.seed, view, level, pass_index, t, colour))
            if probe is not None:
                probe.before(state, ctx, colour, cpre, pattern, key, params, t)
            counts += half_step(state, ctx, colour, cpre, pattern, key, params)
            if probe is not None:
                probe.after(state, colour)
        if on_iteration is not None:
            on_iteration(t, counts, time.perf_counter() - t0)
        total += counts
        if last:
            break
        # the pass's last iteration accepts any lower cost (min_improvement off): it also ends a converged pass
        last = t + 1 == n_iter - 1 or (convergence is not None and convergence.update(state.depth))
    # the caches are only valid within this pass (ctx). Carrying the final hypotheses' photometric costs to the
    # next pass (drop_caches(keep_costs_of=ctx)) would hold 20 B/px for every view until then (79 MB of
    # fountain_p11 768's peak) to spare under 1 % of PatchMatch's time: the next init_cost recomputes them,
    # bit for bit (float32)
    state.drop_caches(pool=pool)
    return total
