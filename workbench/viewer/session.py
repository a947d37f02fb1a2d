"""A viewer session: one scene, its cached PatchMatch maps, and a cache per downstream stage.

The data flow is one way — maps -> filter (pipeline, its confidence threshold, k) -> fusion (thresholds) ->
evaluation — and each stage is cached under the options it depends on, so a change recomputes only what lies
downstream of it. Cheap previews mask the *unfiltered* fused cloud by its per-point attributes
(mean confidence, supporting views) and answer at once; the exact recomputation follows.

Nothing here imports viser: the session is driven by ``workbench/viewer/app.py`` and by tests.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.errors import DeepCError
from engine.core.words import plural
from engine.evaluation import EvaluationOptions, PointIndex, evaluate_points
from engine.fusion import DEFAULT_PRESET, FUSION_PRESETS, FusedCloud, FusionOptions, fuse, views_from_scene
from engine.io.ply import read_points
from engine.run.folder import RunMetrics, read_run_metrics
from engine.run.fused_maps import FusedMaps, FusionRule, RunViewMaps, candidate_maps, fused_maps, read_run_views
from engine.scene import Scene, SceneOptions, load_scene
from workbench.maps.images import colorize, normal_to_rgb, view_images
from workbench.viewer.legends import NO_DATA, Scale, categories_html, histogram_html, note_html, scale_html

# "error" alone names two quantities (the live view's depth error in %, this distance in cm): each mode says its unit
GT_DISTANCE = "GT distance (cm)"
COLOR_MODES = ("rgb", "confidence", "views", GT_DISTANCE)
REPORT_TOLERANCE = 0.02  # the paper's and ETH3D's headline tolerance (model units: metres)
ERROR_SATURATION = 2 * REPORT_TOLERANCE  # the error colouring saturates here (4 cm)
DEPTH_ERROR_PCT = 5.0  # the per-view GT depth error map saturates here (percent of the GT depth)
# The kept-mask colours: what the pipeline's filters did to each pixel of a view.
KEPT, REMOVED_TAU, REMOVED_K = (235, 235, 235), (230, 120, 30), (60, 110, 220)


def _no_data(rgb: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    rgb[invalid] = NO_DATA
    return rgb


# Without a run (tests, benchmarks) ViewParams() starts in `dense` (one median point per cluster), not in the
# pipelines' per-pixel default:
# per-pixel clouds are 3-4x larger, and under five tabs at 50 events per second they doubled the preview
# latency (p50 45 -> 113 ms) and pushed the last exact result past 2 s (benchmarks/bench_viewer_load.py).
# A run opens on its own options instead (ViewerSession.run_params).
VIEWER_DEFAULT_PRESET = "dense"


@dataclasses.dataclass(frozen=True)
class ViewParams:
    """Everything downstream of PatchMatch that the viewer lets a user tune."""

    pipeline: str = "vanilla"
    # the pipeline's confidence filter (FusionRule.fused_confidence_tau): confidence.tau under fast,
    # refinement.refined_confidence_tau under full, nothing under vanilla
    fused_confidence_tau: float = FusionRule().fused_confidence_tau
    mask_k: int = 0  # 0 = no counter filter
    fusion: FusionOptions = dataclasses.field(default_factory=lambda: FUSION_PRESETS[VIEWER_DEFAULT_PRESET])

    def filter_key(self) -> tuple:
        tau = self.fused_confidence_tau if self.pipeline != "vanilla" else 0.0
        return (self.pipeline, round(tau, 6), self.mask_k)

    def fusion_key(self) -> tuple:
        return (self.filter_key(), tuple(sorted(self.fusion.to_dict().items())))


# Exact clouds are bounded by bytes as well as by count: a per-pixel cloud of 11 views at 768 px is
# about 190 MB, so eight of them would hold 1.5 GB for recomputations that take a second or two.
CLOUD_CACHE_BYTES = 512 * 2**20


def _nbytes(value) -> int:
    """Bytes of the numpy arrays a cached value holds directly or in its dataclass fields."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if dataclasses.is_dataclass(value):
        return sum(_nbytes(getattr(value, f.name)) for f in dataclasses.fields(value))
    return 0


class _LRU(OrderedDict):
    """Least-recently-stored cache of at most ``size`` entries and, with ``max_bytes``, at most that many
    bytes of arrays (the newest entry is always kept)."""

    def __init__(self, size: int, max_bytes: int | None = None):
        super().__init__()
        self.size = size
        self.max_bytes = max_bytes

    def put(self, key, value):
        self[key] = value
        self.move_to_end(key)
        while len(self) > self.size:
            self.popitem(last=False)
        if self.max_bytes is not None:
            while len(self) > 1 and sum(_nbytes(v) for v in self.values()) > self.max_bytes:
                self.popitem(last=False)


class ViewerSession:
    """Scene + maps + stage caches. Thread-safe: stage computations are serialised by a lock."""

    def __init__(self, scene: Scene, data: list[RunViewMaps] | None, out_dir: Path | None = None,
                 run: RunMetrics | None = None):
        self.scene = scene
        self.data = data
        self.out_dir = out_dir
        self.run = run  # metrics.json of the run, when a run folder was opened
        self._rules: dict[str, FusionRule] = {}  # per pipeline, under the run's options (run_rule)
        self._cache_lock = threading.Lock()  # held only for dict access: lookups never wait on a computation
        self._compute_lock = threading.RLock()  # serialises the computations themselves
        self._filtered = _LRU(4)
        self._clouds = _LRU(8, CLOUD_CACHE_BYTES)
        self._base_clouds = _LRU(2)  # kept apart so exact clouds never evict what previews need
        self._evals = _LRU(16)
        self._gt_points: np.ndarray | None = None
        self._gt_views: list | None = None
        self._gt_point_index: PointIndex | None = None
        self._gt_lock = threading.RLock()  # the GT is read once, by whichever thread needs it first

    # ---- opening ------------------------------------------------------------------------------
    @classmethod
    def open(cls, path: str | Path, scene_options: SceneOptions | None = None) -> ViewerSession:
        """Open the output folder of ``deepc run`` (metrics.json + stereo maps) or a bare scene."""
        path = Path(path)
        if not path.exists():
            raise DeepCError("does not exist", path)
        if (path / "metrics.json").is_file():
            metrics = read_run_metrics(path)
            scene_path = Path(metrics.scene_path)
            if not (scene_path / "sparse").is_dir():
                raise DeepCError(f"the scene this run was made from is gone ({scene_path})", path / "metrics.json")
            options = scene_options or SceneOptions.from_dict(metrics.scene_options())
            scene = load_scene(scene_path, options)
            return cls(scene, read_run_views(path, scene), path, metrics)
        if (path / "sparse").is_dir() or (path / "sparse" / "0").is_dir():
            return cls(load_scene(path, scene_options or SceneOptions()), None, None)
        raise DeepCError("neither an output folder of deepc run (no metrics.json) nor a COLMAP workspace", path)

    # ---- what exists ----------------------------------------------------------------------------
    @property
    def has_maps(self) -> bool:
        return self.data is not None

    @property
    def pipelines(self) -> list[str]:
        if not self.data:
            return []
        found = ["vanilla"]
        if all(d.confidence is not None for d in self.data):
            found.append("fast")
            if all(d.refined_depth is not None for d in self.data):
                found.append("full")
        return found

    @property
    def has_confidence(self) -> bool:
        return "fast" in self.pipelines

    @property
    def has_counter(self) -> bool:
        return bool(self.data) and all(d.counter is not None for d in self.data)

    @property
    def has_gt(self) -> bool:
        return self.scene.has_gt_points

    def run_rule(self, pipeline: str) -> FusionRule:
        """What ``pipeline`` fuses under the run's own options (``engine.run.fused_maps``; keys an older run did not
        write take ``deepc run``'s defaults, and so does everything without a run)."""
        if pipeline not in self._rules:  # parsed once: every map drawn asks
            self._rules[pipeline] = FusionRule.from_saved(self.run.options if self.run is not None else None, pipeline)
        return self._rules[pipeline]

    def rule(self, params: ViewParams) -> FusionRule:
        """The run's rule for ``params.pipeline`` with the viewer's threshold and counter filter."""
        return dataclasses.replace(self.run_rule(params.pipeline), fused_confidence_tau=params.fused_confidence_tau,
                                   mask_k=params.mask_k)

    @property
    def sky_filter(self) -> bool:
        """Whether ``full`` drops sky and far-plane pixels here (the run's ``refinement.sky_filter``; the viewer
        has no control for it, so it follows the run)."""
        return self.run_rule("full").sky_filter

    def run_params(self) -> ViewParams:
        """The settings the run itself used (its metrics.json options): pipeline, its confidence threshold and
        fusion thresholds. Keys an older run did not write take ``deepc run``'s defaults; without a run, or for
        a pipeline whose maps are missing, the first available pipeline with ``ViewParams()``'s values."""
        if self.run is None:
            return ViewParams(pipeline=(self.pipelines or ["vanilla"])[0])
        options = self.run.options or {}
        fusion = FUSION_PRESETS[DEFAULT_PRESET]
        if isinstance(options.get("fusion"), dict):
            fusion = FusionOptions.from_dict(options["fusion"])
        pipeline = self.run.pipeline if self.run.pipeline in self.pipelines else (self.pipelines or ["vanilla"])[0]
        return ViewParams(pipeline=pipeline, fused_confidence_tau=self.run_rule(pipeline).fused_confidence_tau,
                          mask_k=0, fusion=fusion)

    @staticmethod
    def threshold_label(pipeline: str) -> str | None:
        """The option the confidence threshold of ``pipeline`` stands for ("confidence.tau", ...); None under
        vanilla."""
        return FusionRule(pipeline).threshold_option

    def run_scores(self) -> dict[float, dict[str, float]] | None:
        """The run's own scores per tolerance (its metrics.json ``eval``), None without them."""
        evaluation = self.run.eval if self.run is not None else None
        if not evaluation or not evaluation.get("tolerances"):
            return None
        return {float(t): {"accuracy": a, "completeness": c, "f1": f} for t, a, c, f in zip(
            evaluation["tolerances"], evaluation["accuracy"], evaluation["completeness"], evaluation["f1"],
            strict=True)}

    @property
    def tolerances(self) -> tuple[float, ...]:
        """The tolerances the viewer scores at: the run's, else the evaluation's defaults."""
        scores = self.run_scores()
        return tuple(sorted(scores)) if scores else EvaluationOptions().tolerances

    # ---- stages -----------------------------------------------------------------------------------
    def _cached(self, cache: _LRU, key, compute):
        with self._cache_lock:
            if key in cache:
                return cache[key]
        with self._compute_lock:
            with self._cache_lock:
                if key in cache:
                    return cache[key]
            value = compute()
            with self._cache_lock:
                cache.put(key, value)
            return value

    def filtered_maps(self, params: ViewParams) -> list[tuple[np.ndarray, np.ndarray]]:
        """(depth, normal) per view after the pipeline's filter (cached by pipeline, τ, k)."""
        if not self.data:
            raise DeepCError("no PatchMatch maps in this session: open the output folder of deepc run")
        if params.pipeline not in self.pipelines:
            raise DeepCError(f"pipeline {params.pipeline!r} has no maps here (available: {', '.join(self.pipelines)})")
        return self._cached(self._filtered, params.filter_key(), lambda: self._filter(params))

    def _filter(self, params: ViewParams) -> list[tuple[np.ndarray, np.ndarray]]:
        return [(f.depth, f.normal) for f in fused_maps(self.scene, self.rule(params), self.data)]

    def candidates(self, i: int, pipeline: str) -> FusedMaps:
        """View ``i``'s maps that ``pipeline`` filters, under the run's own options (nothing dropped yet)."""
        return candidate_maps(self.run_rule(pipeline), self.data[i])

    def cloud(self, params: ViewParams, _cache: _LRU | None = None) -> FusedCloud:
        """The exactly fused cloud for ``params`` (cached by filter and fusion options)."""
        def compute() -> FusedCloud:
            maps = self.filtered_maps(params)
            confidence = ([self.candidates(i, params.pipeline).confidence for i in range(len(self.data))]
                          if self.has_confidence else None)
            views = views_from_scene(self.scene, [m[0] for m in maps], [m[1] for m in maps], confidence,
                                     params.fusion.check_num_images)
            return fuse(views, params.fusion)
        return self._cached(self._clouds if _cache is None else _cache, params.fusion_key(), compute)

    def cached_cloud(self, params: ViewParams) -> FusedCloud | None:
        """The cloud for ``params`` if it is already computed, else None (never computes)."""
        with self._cache_lock:
            key = params.fusion_key()
            return self._clouds.get(key, self._base_clouds.get(key))

    def cached_scores(self, params: ViewParams) -> dict[str, float] | None:
        """The scores of ``params``' cloud if already computed, else None (never computes)."""
        with self._cache_lock:
            return self._evals.get(params.fusion_key())

    def nearest_base_cloud(self, params: ViewParams) -> tuple[FusedCloud | None, bool]:
        """The base cloud previews of ``params`` should mask, never computing: its own when cached (True),
        else the newest cached base cloud of the same pipeline with other fusion thresholds (False), else
        (None, False)."""
        base = self.base_params(params)
        with self._cache_lock:
            own = self._base_clouds.get(base.fusion_key())
            if own is not None:
                return own, True
            pipeline = base.filter_key()
            for key in reversed(self._base_clouds):  # newest first
                if key[0] == pipeline:
                    return self._base_clouds[key], False
        return None, False

    def base_cloud(self, params: ViewParams) -> FusedCloud:
        """The cloud of ``params`` with no confidence or counter filter and at least 1 view: the
        superset that previews mask."""
        return self.cloud(self.base_params(params), self._base_clouds)

    @staticmethod
    def base_params(params: ViewParams) -> ViewParams:
        """``params`` without the filters that previews emulate."""
        return dataclasses.replace(params, fused_confidence_tau=0.0, mask_k=0,
                                   fusion=params.fusion.replace(min_num_pixels=1))

    @staticmethod
    def preview_mask(base: FusedCloud, params: ViewParams) -> np.ndarray:
        """Approximate the exact cloud by masking the base cloud by per-point attributes (fast).

        Exact for the fusion's minimum pixel count (the traversal does not depend on it); approximate
        for the confidence threshold and mask-k, which act on pixels before fusion."""
        keep = base.num_pixels >= max(1, params.fusion.min_num_pixels)
        tau = params.fused_confidence_tau
        if params.pipeline != "vanilla" and tau > 0 and np.isfinite(base.mean_confidence).any():
            with np.errstate(invalid="ignore"):
                keep &= base.mean_confidence >= tau
        if params.mask_k > 0:
            keep &= base.num_views >= params.mask_k + 1
        return keep

    def evaluate(self, params: ViewParams, cloud: FusedCloud | None = None) -> dict[str, Any] | None:
        """Accuracy, completeness, F1 (percent) at 2 cm against the GT points, and under ``by_tolerance``
        the same at every tolerance of :attr:`tolerances`; None without GT."""
        if not self.has_gt:
            return None
        def compute() -> dict[str, float]:
            points = self.cloud(params) if cloud is None else cloud
            _, gt_views = self._ground_truth()
            tolerances = tuple(sorted({*self.tolerances, REPORT_TOLERANCE}))
            result = evaluate_points(np.asarray(points.xyz, np.float64), self._gt_index(),
                                     EvaluationOptions(tolerances=tolerances), gt_views)
            return {**result.at(REPORT_TOLERANCE), "by_tolerance": {t: result.at(t) for t in tolerances}}
        return self._cached(self._evals, params.fusion_key(), compute)

    def _ground_truth(self) -> tuple[np.ndarray, list | None]:
        with self._gt_lock:
            if self._gt_points is None:
                self._gt_points = read_points(self.scene.gt_points_path)
                self._gt_views = self.scene.gt_views() or None
            return self._gt_points, self._gt_views

    def _gt_index(self) -> PointIndex:
        """The GT points' search index, built once (1M points: about a second, too slow for every change)."""
        with self._gt_lock:
            if self._gt_point_index is None:
                self._gt_point_index = PointIndex(self._ground_truth()[0])
            return self._gt_point_index

    # ---- colours and per-view images ----------------------------------------------------------------
    def color_modes(self) -> dict[str, str | None]:
        """Every colour mode with the reason it is unavailable here (None: available)."""
        return {"rgb": None,
                "confidence": None if self.has_confidence else "unavailable: the run wrote no confidence maps",
                "views": None,
                GT_DISTANCE: None if self.has_gt else "unavailable: the scene has no GT points"}

    def cloud_scale(self, mode: str) -> Scale | None:
        """The colour scale of a cloud colour mode (None for the images' own colours)."""
        if mode == "confidence":
            return Scale("mean confidence of the fused pixels", 0.0, 1.0, "viridis",
                         no_data="no confidence (fused without)")
        if mode == "views":
            return Scale("views supporting the point", 1, max(2, len(self.scene.views)), "plasma", "views", digits=0)
        if mode == GT_DISTANCE:
            return Scale("distance to the nearest GT point", 0.0, 100 * ERROR_SATURATION, "RdYlGn_r", "cm",
                         saturates=True, digits=1)
        return None

    def cloud_legend(self, mode: str) -> str:
        """HTML legend of a colour mode, or the reason it is unavailable."""
        reason = self.color_modes().get(mode)
        if reason:
            return note_html(f"{mode}: {reason}")
        scale = self.cloud_scale(mode)
        return scale_html(scale) if scale else note_html("colours of the images the points were fused from")

    def colors(self, cloud: FusedCloud, mode: str) -> np.ndarray:
        """(N, 3) uint8 colours of the cloud for a colour mode (:meth:`cloud_scale`); a mode without its data
        (:meth:`color_modes`) is a DeepCError."""
        if mode not in COLOR_MODES:
            raise DeepCError(f"unknown colour mode {mode!r} (one of {', '.join(COLOR_MODES)})")
        reason = self.color_modes()[mode]
        if reason:
            raise DeepCError(f"colour mode {mode}: {reason}")
        if mode == "rgb" or len(cloud) == 0:
            return cloud.rgb
        scale = self.cloud_scale(mode)
        if mode == "confidence":
            values = cloud.mean_confidence
            missing = ~np.isfinite(values)
            return _no_data(colorize(np.nan_to_num(values, nan=0.0)[None, :], 0.0, 1.0, scale.cmap)[0], missing)
        if mode == "views":
            return colorize(cloud.num_views[None, :].astype(np.float32), scale.vmin, scale.vmax, scale.cmap)[0]
        return self.gt_distance_colors(np.asarray(cloud.xyz))

    def gt_distance_colors(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) uint8 colours of points ``xyz`` ((N, 3), model units) by their distance to the nearest GT point,
        on the scale of :meth:`cloud_scale` (GT_DISTANCE: cm, saturating at ``ERROR_SATURATION``); the cloud's
        colour mode and the mesh's vertices share it. Needs GT points (:attr:`has_gt`)."""
        # workers=-1 also releases the GIL, so the viewer's websocket thread keeps sending meanwhile
        dist, _ = self._gt_index().tree.query(np.asarray(xyz, np.float64), k=1,
                                              distance_upper_bound=2 * ERROR_SATURATION, workers=-1)
        return colorize(np.minimum(dist, ERROR_SATURATION)[None, :], 0.0, ERROR_SATURATION,
                        self.cloud_scale(GT_DISTANCE).cmap)[0]

    def view_maps(self, i: int, params: ViewParams) -> dict[str, tuple[np.ndarray, str]]:
        """View ``i``'s maps as the pipeline and filters of ``params`` use them, each an (image, HTML legend):
        image, depth, refined depth (full), normal, cost, counter, confidence, kept mask, GT depth error."""
        view = self.scene.views[i]
        out = {"image": ((np.asarray(self.scene.image(i)) * 255 + 0.5).astype(np.uint8),
                         note_html("the view's image"))}
        if not self.data:
            return out
        d = self.data[i]
        lo, hi = view.depth_range
        maps = self.candidates(i, params.pipeline)
        depth, normal, confidence, counter = maps.depth, maps.normal, maps.confidence, maps.counter
        missing = ~(depth > 0)

        def scalar(key: str, values: np.ndarray, scale: Scale, invalid: np.ndarray) -> None:
            rgb = colorize(np.minimum(values, scale.vmax), scale.vmin, scale.vmax, scale.cmap)
            out[key] = (_no_data(rgb, invalid), scale_html(scale))

        scalar("depth", d.depth, Scale("depth (PatchMatch)", lo, hi, "turbo", "m", no_data="no estimate"),
               ~(d.depth > 0))
        if params.pipeline == "full" and d.refined_depth is not None:
            scalar("refined depth", depth, Scale("depth fused by full (refined where network 1 doubts)", lo, hi,
                                                 "turbo", "m", no_data="no estimate"), missing)
        out["normal"] = (_no_data(normal_to_rgb(normal), ~normal.any(axis=2)),
                         note_html("normal: RGB = (n + 1) / 2 of its x, y, z in the camera frame; grey: no estimate"))
        if d.cost is not None:
            scalar("cost", d.cost, Scale("matching cost (1 − NCC)", 0.0, 2.0, "magma", no_data="no estimate"),
                   ~(d.depth > 0))
        if counter is not None:
            scalar("counter", counter.astype(np.float32),
                   Scale("counter: consistent source views", 0, max(1, len(view.source_views)), "viridis", "views",
                         no_data="no estimate", digits=0), missing)
        if confidence is not None:
            scalar("confidence", confidence, Scale("confidence", 0.0, 1.0, "viridis", no_data="no estimate"), missing)
        kept = self.filtered_maps(params)[i][0] > 0
        by_tau = np.zeros_like(missing)
        tau, tau_name = params.fused_confidence_tau, self.threshold_label(params.pipeline)
        if params.pipeline != "vanilla" and tau > 0 and confidence is not None:
            by_tau = ~missing & (confidence < tau)
        mask = np.empty(depth.shape + (3,), np.uint8)
        mask[:] = REMOVED_K
        mask[kept] = KEPT
        mask[by_tau] = REMOVED_TAU
        mask[missing] = NO_DATA
        entries = [(KEPT, "kept (fused)")]
        if by_tau.any() or (params.pipeline != "vanilla" and tau > 0):
            entries.append((REMOVED_TAU, f"removed by {tau_name} {tau:g}"))
        if params.mask_k > 0:
            entries.append((REMOVED_K, f"removed by mask k {params.mask_k}"))
        entries.append((NO_DATA, "no estimate"))
        out["kept"] = (mask, categories_html("kept mask (pipeline filters)", entries))
        gt = self.scene.gt_depth(i) if self.scene.has_gt_depth else None
        if gt is not None:
            valid = kept & (gt > 0)
            rel = np.where(valid, np.abs(depth - gt) / np.where(gt > 0, gt, 1.0), 0.0) * 100
            scalar("GT error", rel.astype(np.float32),
                   Scale("depth error of the kept pixels vs GT", 0.0, DEPTH_ERROR_PCT, "RdYlGn_r", "%",
                         no_data="not kept, or no GT depth", saturates=True, digits=1), ~valid)
        return out

    def view_metrics(self, i: int, params: ViewParams) -> str:
        """One view's numbers under ``params``: estimates, kept pixels, and their error against GT depth."""
        depth = self.candidates(i, params.pipeline).depth if self.data else None
        if depth is None:
            return "no maps"
        kept = self.filtered_maps(params)[i][0] > 0
        pixels = depth.size
        lines = [f"estimates {100 * (depth > 0).sum() / pixels:.1f} % · kept {100 * kept.sum() / pixels:.1f} % "
                 f"of {pixels:,} pixels"]
        gt = self.scene.gt_depth(i) if self.scene.has_gt_depth else None
        if gt is not None:
            valid = kept & (gt > 0)
            if valid.any():
                rel = np.abs(depth[valid] - gt[valid]) / gt[valid]
                lines.append(f"kept vs GT depth: abs rel {rel.mean():.4f} · within 1 % {100 * (rel < 0.01).mean():.1f} "
                             f"% · within 5 % {100 * (rel < 0.05).mean():.1f} %")
        else:
            lines.append("no GT depth for this view")
        return "  \n".join(lines)

    def histograms(self, params: ViewParams) -> list[str]:
        """HTML histograms of the pipeline's confidence (with τ) and counter (with mask k) over every view's
        estimates: where a threshold cuts."""
        if not self.data:
            return []
        key = ("hist", params.pipeline)
        with self._cache_lock:
            counts = self._evals.get(key)
        if counts is None:
            maps = [self.candidates(i, params.pipeline) for i in range(len(self.data))]
            counts = {}
            if all(m.confidence is not None for m in maps):
                values = np.concatenate([m.confidence[m.depth > 0] for m in maps])
                counts["confidence"] = np.histogram(values, bins=40, range=(0.0, 1.0))
            if all(m.counter is not None for m in maps):
                values = np.concatenate([m.counter[m.depth > 0] for m in maps])
                top = max(1, int(values.max()) if len(values) else 1)
                counts["counter"] = np.histogram(values, bins=np.arange(top + 2) - 0.5)
            with self._cache_lock:
                self._evals.put(key, counts)
        out = []
        if "confidence" in counts:
            tau = params.fused_confidence_tau if params.pipeline != "vanilla" else None
            name = self.threshold_label(params.pipeline) or "τ"
            out.append(histogram_html(f"confidence of the {params.pipeline} estimates", *counts["confidence"], tau,
                                      threshold_name=name, below=f"below {name} (removed)" if tau else ""))
        if "counter" in counts:
            out.append(histogram_html("counter: consistent source views per estimate", *counts["counter"],
                                      params.mask_k - 0.5 if params.mask_k > 0 else None,
                                      threshold_name="mask k", below="below k (removed)", shown=str(params.mask_k),
                                      axis=("0", plural(len(counts["counter"][0]) - 1, "view"))))
        return out

    def view_images(self, i: int) -> dict[str, np.ndarray]:
        """uint8 RGB images of view ``i``'s maps for the side panel: image, depth, normal, counter, confidence."""
        return view_images(self.scene, i, self.data[i] if self.data else None)


def describe(scores: dict[str, Any] | None) -> str:
    if not scores:
        return "no ground truth"
    return (f"F1 {scores['f1']:.1f} · accuracy {scores['accuracy']:.1f} · "
            f"completeness {scores['completeness']:.1f} (at {REPORT_TOLERANCE * 100:.0f} cm)")
