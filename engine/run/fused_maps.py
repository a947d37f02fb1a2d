"""The maps a pipeline fuses, given the run's options: the one place that says so.

Kuhn et al. 2020: ``vanilla`` fuses PatchMatch's depth and normal maps as they are; ``fast`` (DeepC-MVS_fast, §4.1)
keeps the pixels whose network-1 confidence is at least ``confidence.tau``; ``full`` (§4.2) fuses the refined maps,
filtered by the confidence network 2 gives them (``refinement.refined_confidence_tau``), and drops sky and far-plane
pixels (§5.5, ``refinement.sky_filter``). Our ``full`` keeps PatchMatch's estimate where network 1 trusts it
(``refinement.keep_confident``, :mod:`engine.refinement.guard`) before that filter.

A :class:`FusionRule` is that choice as a value, made from a run's options (:meth:`FusionRule.from_options`) or
from what a run saved (:meth:`FusionRule.from_saved`); :func:`fused_view` applies it to one view's maps
(:class:`RunViewMaps`). The in-process pipeline, the streamed (``--executor dask``) stages, the viewer, ``deepc
mesh --method tsdf`` and the run summary all go through here, so what they show or integrate is what the run
fused. The viewer also filters by counter maps (``mask_k``, the paper's "mask-k" baselines of §4.1): the same rule
with that filter added.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any

import numpy as np

from engine.confidence.options import ConfidenceOptions
from engine.core.errors import DeepCError
from engine.core.options import Options
from engine.filtering import filter_by_confidence, filter_by_counter
from engine.refinement.guard import keep_confident, kept_estimates
from engine.refinement.options import RefinementOptions
from engine.refinement.sky import SkyOptions
from engine.refinement.views import sky_filter_view
from engine.run.folder import read_map
from engine.scene import Scene

PIPELINES = ("vanilla", "fast", "full")
#: the option each pipeline's confidence filter reads (vanilla has none)
THRESHOLD_OPTIONS = {"fast": "confidence.tau", "full": "refinement.refined_confidence_tau"}


@dataclasses.dataclass(frozen=True)
class FusionRule:
    """Which maps a pipeline fuses and how they are filtered first.

    Attributes:
        pipeline: ``vanilla``, ``fast`` or ``full``.
        fused_confidence_tau: pixels whose fused confidence is below this are dropped (fast and full; c >= it is
            kept): ``confidence.tau`` under fast, ``refinement.refined_confidence_tau`` under full.
        keep_confident: under full, PatchMatch's estimate is fused where network 1's confidence is at least this
            (None: every pixel refined, the paper's rule).
        sky_filter: under full, sky and far-plane pixels are dropped after the confidence filter (§5.5).
        sky: that filter's mask and far-plane cut (``refinement.sky``).
        mask_k: also drop pixels with fewer consistent source views (0: no counter filter; no pipeline
            applies one, the viewer may).
    """

    pipeline: str = "vanilla"
    fused_confidence_tau: float = ConfidenceOptions().tau
    keep_confident: float | None = RefinementOptions().keep_confident
    sky_filter: bool = RefinementOptions().sky_filter
    mask_k: int = 0
    sky: SkyOptions = dataclasses.field(default_factory=SkyOptions)

    def __post_init__(self) -> None:
        if self.pipeline not in PIPELINES:
            raise DeepCError(f"unknown pipeline {self.pipeline!r} (one of {', '.join(PIPELINES)})")

    @classmethod
    def from_options(cls, options: Any) -> FusionRule:
        """The rule of a run made with ``options`` (an :class:`engine.run.pipeline.PipelineOptions`)."""
        return cls.of(options.pipeline, options.confidence, options.refinement)

    @classmethod
    def from_saved(cls, saved: dict[str, Any] | None, pipeline: str) -> FusionRule:
        """The rule of a finished run of ``pipeline`` from the options its metrics.json saved (``options``): former
        option names are read (``Options`` aliases); options a run did not save take their defaults, or the value
        that reproduces a run made before they existed."""
        saved = saved or {}

        def section(key: str, kind: type) -> Any:
            return kind.from_dict(_known(kind, saved.get(key) or {}), saved=True)

        return cls.of(pipeline, section("confidence", ConfidenceOptions), section("refinement", RefinementOptions))

    @classmethod
    def of(cls, pipeline: str, confidence: ConfidenceOptions, refinement: RefinementOptions) -> FusionRule:
        """The rule of ``pipeline`` run with these stage options."""
        tau = refinement.refined_confidence_tau if pipeline == "full" else confidence.tau
        return cls(pipeline, tau, refinement.keep_confident, refinement.sky_filter, sky=refinement.sky)

    @property
    def threshold_option(self) -> str | None:
        """The option :attr:`fused_confidence_tau` comes from (``confidence.tau``, ...); None under vanilla."""
        return THRESHOLD_OPTIONS.get(self.pipeline)

    def kinds(self) -> tuple[str, ...]:
        """The maps of a run folder the rule reads (``engine.run.folder`` kinds)."""
        kinds = ("depth", "normal") + (("counter",) if self.mask_k > 0 else ())
        if self.pipeline == "fast":
            return kinds + ("confidence",)
        if self.pipeline == "full":
            return kinds + ("confidence", "refined_depth", "refined_normal", "refined_confidence") + (
                ("refined_counter",) if self.mask_k > 0 else ())
        return kinds


def _known(kind: type, data: dict[str, Any]) -> dict[str, Any]:
    """``data`` without the keys ``kind`` (an ``Options`` class) no longer has, in nested options too: a saved run
    may hold options since removed (``refinement.sky.enabled``, now ``refinement.sky_filter``)."""
    out = {}
    for key, value in data.items():
        name = kind.field_name(key)
        if name is None:
            continue
        nested = typing.get_type_hints(kind).get(name)
        out[key] = _known(nested, value) if isinstance(value, dict) and isinstance(nested, type) and issubclass(
            nested, Options) else value
    return out


@dataclasses.dataclass
class RunViewMaps:
    """The maps of one view as a run holds them (None where it has none); (H, W) each, normals (H, W, 3)."""

    depth: np.ndarray  # PatchMatch depth, 0 = none
    normal: np.ndarray
    counter: np.ndarray | None = None  # consistent source views of the PatchMatch estimate (§3.2)
    confidence: np.ndarray | None = None  # network 1 on the PatchMatch maps, in [0, 1]
    refined_depth: np.ndarray | None = None
    refined_normal: np.ndarray | None = None
    refined_counter: np.ndarray | None = None  # counter maps of the refined maps (older full runs: None)
    refined_confidence: np.ndarray | None = None  # network 2 on the refined maps (older full runs: None)
    cost: np.ndarray | None = None  # PatchMatch's matching cost (1 - NCC, 0..2)


@dataclasses.dataclass
class FusedMaps:
    """(H, W) depth, (H, W, 3) normal, (H, W) confidence and counter of one view (None where absent)."""

    depth: np.ndarray
    normal: np.ndarray
    confidence: np.ndarray | None
    counter: np.ndarray | None


def candidate_maps(rule: FusionRule, view: RunViewMaps) -> FusedMaps:
    """The maps ``rule``'s pipeline filters before fusion (nothing dropped yet): PatchMatch's (vanilla, fast); under
    full the refined maps with their own confidence and counter maps, PatchMatch's where network 1's confidence
    is at least ``rule.keep_confident`` (the first network's maps for older full runs without network 2's)."""
    if rule.pipeline != "full":
        return FusedMaps(view.depth, view.normal, view.confidence, view.counter)
    if view.refined_depth is None or view.refined_normal is None:
        raise DeepCError("the run has no refined maps: a full pipeline fuses them")
    counter = view.counter if view.refined_counter is None else view.refined_counter
    if view.refined_confidence is None or view.confidence is None:
        return FusedMaps(view.refined_depth, view.refined_normal, view.confidence, counter)
    depth, normal, confidence = keep_confident(view.depth, view.normal, view.confidence, view.refined_depth,
                                               view.refined_normal, view.refined_confidence, rule.keep_confident)
    if view.counter is not None and counter is not None:
        counter = np.where(kept_estimates(view.depth, view.confidence, rule.keep_confident), view.counter, counter)
    return FusedMaps(depth, normal, confidence, counter)


def fused_view(scene: Scene, i: int, rule: FusionRule, view: RunViewMaps) -> FusedMaps:
    """View ``i`` of ``scene`` as ``rule``'s pipeline fuses it: :func:`candidate_maps` with the dropped pixels' depth
    and normal zeroed (confidence below ``rule.fused_confidence_tau``, counter below ``rule.mask_k``, then sky and
    far plane under full with ``rule.sky_filter``); confidence and counter stay those of the candidates."""
    maps = candidate_maps(rule, view)
    depth, normal = maps.depth, maps.normal
    if rule.pipeline != "vanilla":
        if maps.confidence is None:
            raise DeepCError(f"the run has no confidence maps: a {rule.pipeline} pipeline filters by them")
        depth, normal = filter_by_confidence(depth, normal, maps.confidence, rule.fused_confidence_tau)
    if rule.mask_k > 0 and maps.counter is not None:
        depth, normal = filter_by_counter(depth, normal, maps.counter, rule.mask_k)
    if rule.pipeline == "full" and rule.sky_filter:
        # the sky heuristic looks at where the *vanilla* maps were unreliable (engine.refinement.sky)
        depth, normal, _ = sky_filter_view(scene, i, depth, normal, view.depth, view.confidence, rule.sky)
    return FusedMaps(depth, normal, maps.confidence, maps.counter)


def fused_maps(scene: Scene, rule: FusionRule, views: list[RunViewMaps]) -> list[FusedMaps]:
    """:func:`fused_view` of every view of ``scene``."""
    return [fused_view(scene, i, rule, view) for i, view in enumerate(views)]


def read_run_view(out_dir: str | Path, name: str, kinds: tuple[str, ...] | None = None) -> RunViewMaps:
    """The maps of view ``name`` in the run folder ``out_dir``: those of ``kinds`` (None: every kind it has; see
    :meth:`FusionRule.kinds`); a missing depth or normal map is a :class:`DeepCError` (:func:`fused_view` names
    any other map its rule misses)."""
    kinds = kinds or tuple(f.name for f in dataclasses.fields(RunViewMaps))
    maps = {kind: read_map(out_dir, kind, name) for kind in kinds}
    if maps.get("depth") is None or maps.get("normal") is None:
        raise DeepCError(f"the run has no depth/normal map for view {name}", Path(out_dir))
    return RunViewMaps(**maps)


def read_run_views(out_dir: str | Path, scene: Scene) -> list[RunViewMaps]:
    """Every map of every view of ``scene`` in the run folder ``out_dir`` (:func:`read_run_view`)."""
    return [read_run_view(out_dir, v.name) for v in scene.views]
