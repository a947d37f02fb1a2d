"""Confidence while PatchMatch runs: every k-th iteration of a view, its counter map and the DeepC confidence.

Kuhn et al. 2020 (DeepC-MVS, §3.2) score the *final* PatchMatch maps: the counter map K (source views whose final
depth confirms a pixel; COLMAP's filter, Schönberger et al. 2016) and the RGB image and normals go into the
confidence network. :class:`LiveConfidence` applies the same two steps to the maps *while* PatchMatch (Xu & Tao 2019
ACMM schedule) converges, so that a user watches the confidence rise where the estimates settle. Every k-th
red-black iteration of a view (its ``view_iteration`` + 1 a multiple of k) it logs, at that iteration's time on the
stream's timelines (``view_iteration``, ``pass``, ``iteration``):

    maps/<view>/counter       consistent source views, class-coded as after PatchMatch (workbench.rerun.legends)
    maps/<view>/confidence    the network's confidence on the current maps, class-coded
    maps/<view>/label         GT labels of the current depth (when the view has GT depth)
    stats/<view>/confidence_kept_pct   share of the view's estimates with confidence >= tau [%]
    stats/<view>/confidence_auc        ROC-AUC x100 of confidence against the labels (when GT exists)
    stats/<view>/confidence_seconds    what this cost [s]

Maps at a coarser pyramid level are smaller than the images: the images are area-resized to the level the way the
engine's pyramid does and the cameras rescaled (``Camera.rescaled``). **Source views at another level.** The
counter of view r at level l reads each source view j's *latest* depth map: j's map at level l when j has one
(j ran before r in this pass, or in an earlier pass of level l); otherwise (the photometric pass of level l has not
reached j yet) j's latest map of the coarser level, resampled to level l's size (depth is camera z, so a coarser
map describes the same surfaces; it is what j's own level l starts from, before its upsampling's edge-aware
refinement); a view with no map yet (the coarsest level's first pass) has depth 0 and confirms nothing. The counter
channel of the network still divides by the number of source views, so early counters (and confidences) are low:
they rise as the other views converge, which is what the stream is meant to show.

Labels use the view's GT depth resampled to the level and the source cameras at the working resolution, so an
estimate is judged by the same 2 px rule at every level (an inlier of a coarse level is one that would count as an
inlier of the final map).

The engine stays pure: this is an observer the rerun stream forwards its events to. Nothing is built, copied or
computed unless a stream asks for it (``StreamOptions.confidence_every`` > 0), and it only reads the events' maps, so
a run's maps are bit-identical with or without it. It runs inline, in the engine's thread: numba's workqueue
threading layer must not launch parallel kernels (the counter kernel) from two threads at once, and PatchMatch keeps
both cores busy (see docs/decisions.md, "Confidence while PatchMatch runs").
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import rerun as rr

from engine.confidence.inputs import network_inputs
from engine.confidence.metrics import roc_auc
from engine.confidence.options import ConfidenceOptions
from engine.consistency import CounterOptions, compute_counter_maps
from engine.core.camera import Camera
from engine.core.observer import IterationEvent, NullObserver
from engine.core.resample import resample_depth
from engine.io.images import resize_area, to_gray
from engine.patchmatch.multiscale import PatchMatchView, ViewMaps
from engine.patchmatch.pyramid import area_resize
from workbench.maps.images import subsample
from workbench.rerun.legends import confidence_classes, counter_classes, label_classes
from workbench.rerun.stream import RerunStream, entity_name

#: torch threads of the live scoring unless ``confidence.num_threads`` says otherwise: between PatchMatch's kernels two
#: OpenMP threads wait at every layer's barrier for a core that another process holds; on the 2-core machine under load
#: one thread scored a 160x120 view in 0.62 s, two in 5.3 s (docs/decisions.md)
LIVE_TORCH_THREADS = 1


class LiveConfidence(NullObserver):
    """Counter and confidence maps of each view every ``every``-th iteration, logged through ``stream``.

    Args:
        stream: the rerun stream that forwards its events here (its timelines, views, GT and thinning).
        every: k >= 1.
        counter: the counter map's checks (``PipelineOptions.counter``).
        confidence: the network's options (``PipelineOptions.confidence``: weights, tau, tiles, bf16; its
            ``num_threads``, else :data:`LIVE_TORCH_THREADS`).
        model: a loaded :class:`engine.confidence.network.ConfidenceNet`; default: load ``confidence.weights`` (the
            shipped network of the fast pipeline), so that ``--pipeline vanilla`` streams confidence too.
    """

    def __init__(self, stream: RerunStream, every: int, counter: CounterOptions | None = None,
                 confidence: ConfidenceOptions | None = None, model: Any = None):
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.stream = stream
        self.every = every
        self.counter_options = (counter or CounterOptions()).validate()
        self.options = (confidence or ConfidenceOptions()).validate()
        if model is None:
            from engine.confidence.weights import load_weights  # lazy: torch

            model = load_weights(self.options.weights or None)
        self.model = model
        self._latest: dict[int, np.ndarray] = {}  # per view: a copy of its latest depth map (any level)
        self._levels: dict[tuple[int, tuple[int, int]], tuple[np.ndarray, np.ndarray, Camera]] = {}
        self.listeners: list[Any] = []  # called as listener(view, confidence) after each scoring (the live viewer)
        self.computed = 0  # view-iterations scored
        self.seconds = 0.0  # spent scoring them

    def on_iteration(self, event: IterationEvent) -> None:
        self._latest[event.view] = event.depth.copy()  # the engine overwrites its state in place
        view_iteration = self.stream.event_time[0]
        wanted_view = self.stream.options.view is None or self.stream.options.view == event.view
        if wanted_view and (view_iteration + 1) % self.every == 0:
            self._score(event)

    # ---- one view ----------------------------------------------------------------------------------
    def _level(self, view: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, Camera]:
        """(grey image, RGB image, camera) of ``view`` at the pyramid level of size ``shape`` (cached)."""
        key = (view, shape)
        if key not in self._levels:
            _name, camera, rgb, _sources = self.stream.views[view]
            h, w = shape
            same = (camera.width, camera.height) == (w, h)
            gray = area_resize(to_gray(rgb), w, h)  # as the engine's pyramid (engine/patchmatch/multiscale.py)
            self._levels[key] = (gray, rgb if same else resize_area(rgb, (w, h)),
                                 camera if same else camera.rescaled(w, h))
        return self._levels[key]

    def source_depth(self, view: int, shape: tuple[int, int]) -> np.ndarray:
        """The latest depth of source ``view`` at ``shape`` (module doc: the rule for views at another level)."""
        depth = self._latest.get(view)
        if depth is None:
            return np.zeros(shape, np.float32)
        return depth if depth.shape == shape else resample_depth(depth, (shape[1], shape[0]))

    def counter_map(self, event: IterationEvent) -> np.ndarray:
        """(H, W) uint8 counter of ``event``'s view against the other views' latest maps (engine.consistency)."""
        shape = event.depth.shape
        name, _camera, _rgb, sources = self.stream.views[event.view]
        sources = [j for j in sources if j < len(self.stream.views)]
        lo, hi = self.stream.depth_range(event.view)
        gray, _rgb, camera = self._level(event.view, shape)
        # compute_counter_maps over [reference, its sources]: the sources have no sources of their own, so only the
        # reference's counter is computed; theirs are skipped (the unused maps share one zero array)
        views = [PatchMatchView(name, gray, camera, lo, hi, list(range(1, len(sources) + 1)))]
        maps = [ViewMaps(np.asarray(event.depth), np.asarray(event.normal), np.asarray(event.cost),
                         np.asarray(event.selected_views))]
        zeros = np.zeros(shape, np.float32)
        for j in sources:
            s_gray, _s_rgb, s_camera = self._level(j, shape)
            s_lo, s_hi = self.stream.depth_range(j)
            views.append(PatchMatchView(self.stream.views[j][0], s_gray, s_camera, s_lo, s_hi, []))
            maps.append(ViewMaps(self.source_depth(j, shape), zeros, zeros, zeros))
        return compute_counter_maps(views, maps, self.counter_options)[0]

    def confidence_map(self, event: IterationEvent, counter: np.ndarray) -> np.ndarray:
        """(H, W) float32 confidence of ``event``'s maps, 0 without depth (as
        ``engine.run.pipeline.confidence_stage``)."""
        from engine.confidence.inference import facing_away, predict_confidence, torch_threads  # lazy: torch

        _gray, rgb, _camera = self._level(event.view, event.depth.shape)
        x = network_inputs(rgb, event.normal, counter, len(self.stream.views[event.view][3]))
        o = self.options
        with torch_threads(o.num_threads or LIVE_TORCH_THREADS):
            c = predict_confidence(self.model, x, o.tile, o.overlap, o.bf16)
        c = np.where(event.depth > 0, c, np.float32(0.0)).astype(np.float32)
        if o.zero_backfacing:
            c[facing_away(x)] = 0.0
        return c

    def _score(self, event: IterationEvent) -> None:
        start = time.perf_counter()
        stream, view = self.stream, event.view
        counter = self.counter_map(event)
        conf = self.confidence_map(event, counter)
        depth = np.asarray(event.depth)
        valid = depth > 0
        small = stream.options.max_size or 0
        invalid = subsample(~valid, small)
        stream.set_event_time()
        stream.log_view_classes(view, "counter", counter_classes(subsample(counter, small), invalid))
        stream.log_view_classes(view, "confidence", confidence_classes(subsample(conf, small), invalid))
        stats = f"stats/{entity_name(view, stream.views[view][0])}"
        kept = 100.0 * float((conf[valid] >= self.options.tau).mean()) if valid.any() else float("nan")
        stream.rec.log(f"{stats}/confidence_kept_pct", rr.Scalars(kept))
        labels = stream.labels(view, depth)
        if labels is not None:
            stream.log_view_classes(view, "label", label_classes(subsample(labels, small)))
            keep = labels >= 0
            stream.rec.log(f"{stats}/confidence_auc", rr.Scalars(100.0 * roc_auc(conf[keep], labels[keep])))
        for listener in self.listeners:
            listener(view, conf)
        seconds = time.perf_counter() - start
        stream.rec.log(f"{stats}/confidence_seconds", rr.Scalars(seconds))
        self.seconds += seconds
        self.computed += 1
