"""The mutable state of one reference view at the current pyramid level: its hypothesis maps and the cost
caches of the pass that runs on it."""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.patchmatch.buffers import BufferPool
from engine.patchmatch.context import ViewContext
from engine.patchmatch.options import ROW_CACHE_MAX_BYTES, row_cache_bytes
from engine.patchmatch.records import CostCaches, HypothesisMaps

# names of the maps in a checkpoint (engine.run.checkpoint), kept from the first format so saved runs resume
CHECKPOINT_NAMES = {"depth": "Z", "normal": "N", "cost": "C", "selected_views": "S"}
__all__ = ["CHECKPOINT_NAMES", "ROW_CACHE_MAX_BYTES", "ViewState", "row_cache_bytes"]


@dataclasses.dataclass
class ViewState:
    """Per-view maps at the current level (``records.HypothesisMaps``) and the cost caches of the running pass
    (``records.CostCaches``; set by ``view_pass.init_cost``, None between passes).

    Between the passes of a level: ``known_costs`` (H, W, N) f32, the last pass's ``view_costs``, with
    ``known_window_set`` (H, W) u8 the window set each pixel matched with (``view_pass.init_cost`` of the next
    pass reuses them)."""

    depth: np.ndarray  # (H, W) f32 camera z, 0 = none
    normal: np.ndarray  # (H, W, 3) f32 unit, camera frame, facing the camera
    cost: np.ndarray  # (H, W) f32 aggregated cost of the stored hypothesis
    selected_views: np.ndarray  # (H, W) u32 bitmask over the view's source views
    view_costs: np.ndarray | None = None  # (H, W, N) f32 (the costs are float32 values)
    versions: np.ndarray | None = None  # (H, W) u32
    row_samples: np.ndarray | None = None  # (H, W, K_up) i8 (patterns have at most 72 samples)
    row_stamps: np.ndarray | None = None  # (H, W) u32
    row_costs: np.ndarray | None = None  # (H, W, K_up, N) f32
    row_count: np.ndarray | None = None  # (H, W) i32
    changed: np.ndarray | None = None  # (H, W) u8
    clock: np.ndarray | None = None  # (1,) u32
    known_costs: np.ndarray | None = None
    known_window_set: np.ndarray | None = None

    @classmethod
    def zeros(cls, height: int, width: int) -> ViewState:
        """Empty maps (no hypothesis anywhere) of an image of ``height`` x ``width`` pixels."""
        return cls(np.zeros((height, width), np.float32), np.zeros((height, width, 3), np.float32),
                   np.zeros((height, width), np.float32), np.zeros((height, width), np.uint32))

    def copy_maps(self) -> ViewState:
        """A state with copies of the maps and no caches."""
        return ViewState(self.depth.copy(), self.normal.copy(), self.cost.copy(), self.selected_views.copy())

    def maps(self) -> HypothesisMaps:
        """The maps as the kernels take them (no copies)."""
        return HypothesisMaps(self.depth, self.normal, self.cost, self.selected_views)

    def caches(self, rows: bool) -> CostCaches:
        """The cost caches as the kernels take them; ``rows``: whether the row cache is used
        (:meth:`prepare_caches`)."""
        return CostCaches(self.view_costs, self.versions, self.row_samples, self.row_stamps, self.row_costs,
                          self.row_count, self.changed, rows, self.clock)

    def checkpoint_arrays(self) -> dict[str, np.ndarray]:
        """The maps a checkpoint saves, under their on-disk names (no copies, unlike ``dataclasses.asdict``,
        which would also deep-copy the caches)."""
        return {disk: getattr(self, name) for name, disk in CHECKPOINT_NAMES.items()}

    @classmethod
    def from_checkpoint(cls, arrays: dict[str, np.ndarray]) -> ViewState:
        """The state of the maps :meth:`checkpoint_arrays` saved (``engine.run.checkpoint`` verified them)."""
        return cls(**{name: arrays[disk] for name, disk in CHECKPOINT_NAMES.items()})

    def prepare_caches(self, n_sources: int, k_up: int, reset: bool, pool: BufferPool | None = None) -> bool:
        """(Re)allocate the cost caches for ``n_sources`` sources and ``k_up`` candidates (from ``pool`` when
        given); ``reset`` empties them (new pass). Returns whether the row cache is used (it is left out above
        ROW_CACHE_MAX_BYTES)."""
        h, w = self.depth.shape
        n = n_sources
        empty = np.empty if pool is None else pool.take
        if self.view_costs is None or self.view_costs.shape != (h, w, n):
            self.view_costs = empty((h, w, n), np.float32)
            self.versions = empty((h, w), np.uint32)
            self.changed = empty((h, w), np.uint8)
            self.clock = np.zeros(1, np.uint32)
            reset = True
        rows = row_cache_bytes(h, w, k_up, n) <= ROW_CACHE_MAX_BYTES
        if not rows:
            self.row_samples, self.row_stamps = np.empty((1, 1, k_up), np.int8), np.empty((1, 1), np.uint32)
            self.row_costs, self.row_count = np.empty((1, 1, k_up, n), np.float32), np.zeros((1, 1), np.int32)
        elif self.row_count is None or self.row_costs.shape != (h, w, k_up, n):
            # contents are never read before written: row_count = 0 (below) makes every cached row unknown
            self.row_samples, self.row_stamps = empty((h, w, k_up), np.int8), empty((h, w), np.uint32)
            self.row_costs, self.row_count = empty((h, w, k_up, n), np.float32), empty((h, w), np.int32)
            self.row_count[:] = 0
        if reset:
            self.view_costs[:] = np.nan
            self.versions[:] = 0
            self.clock[:] = 0
            self.changed[:] = 1  # every pixel's first update in a pass is active
            self.row_count[:] = 0
        return rows

    def drop_caches(self, keep_costs_of: ViewContext | None = None, pool: BufferPool | None = None) -> None:
        """Free the pass's caches (into ``pool`` when given); with ``keep_costs_of`` (the pass's context) keep
        the photometric costs of the stored hypotheses for the next pass at this level (float32 holds them
        exactly)."""
        if keep_costs_of is not None and self.view_costs is not None:
            # the context's wset is never pooled: keeping a reference is enough
            self.known_costs, self.known_window_set = self.view_costs.astype(np.float32), keep_costs_of.wset
        else:
            self.known_costs = self.known_window_set = None
        if pool is not None:
            pool.give(self.view_costs, self.versions, self.row_samples, self.row_stamps, self.row_costs,
                      self.row_count, self.changed)
        self.view_costs = self.versions = self.row_samples = self.row_stamps = self.row_costs = None
        self.changed = self.clock = None
        self.row_count = None
