"""Peak memory of ``deepc run``, estimated from the scene and options before anything heavy starts.

The estimate is the process's resident memory now (interpreter, libraries, the loaded scene: measured,
not guessed) plus the arrays each stage holds at its worst moment, counted from the code:

- inputs: the grey images PatchMatch takes (4 B/px) and decoding the largest original image (uint8 RGB + two float32
  copies); the RGB float32 cache of every view (12 B/px, at most 64 views cached) is emptied before PatchMatch and
  filled again by the stages after it (``engine.run.pipeline``);
- PatchMatch (Xu & Tao 2019): image pyramids (4 B/px × 4/3), every view's depth (4 B/px; a view's normal, cost and
  selected views, 20 B/px, are parked in the checkpoint between its passes: ``engine.patchmatch.multiscale``),
  the geometric-pass depth snapshot (4 B/px), the coarser level's states during upsampling (24/4 B/px),
  and for the view being processed its context (window moments and choice, padded source images and
  source depths: 4·(2 + 2·sources) + 1 B/px) and its cost caches (``ViewState.prepare_caches``: float32 costs
  of the stored hypotheses, stamps and flags, 4·sources + 5 B/px, and the candidate rows);
- after PatchMatch: every view's maps (24 B/px) and counter map (1 B/px); the RGB cache again, fusion's copy of every
  view in its slots (23 B/px: depth, normal, colour, confidence) and one output chunk with its PLY records (the cloud
  is written into ``fused.ply`` as it is made and stays there: ``engine/fusion/stream.py``), then, the images
  forgotten, the evaluation a chunk of points at a time (``engine/evaluation/chunked.py``: a chunk and a slab of
  voxels, about 60 MiB, and the GT views packed, 4 B/px, besides the GT points' index, ~44 B each, and ~44 B
  each while their voxels are counted).

The compiled kernels (numba, and the LLVM runtime it links them with) take tens of MiB the first time
one runs; :func:`load_kernels` runs a 2-view 24×24 PatchMatch first so that this is part of the measured
baseline rather than a guess.

``deepc run`` refuses a run whose estimate exceeds the memory available (``/proc/meminfo``
MemAvailable plus what the process already holds) and names a ``--max-image-size`` that fits; it does not
downsize on its own, because that would silently change the results. ``--ignore-memory-check``
overrides. ``benchmarks/performance/bench_memory.py`` compares estimates with measured peaks.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.camera import Camera, rescaled_size
from engine.patchmatch.options import ROW_CACHE_MAX_BYTES, PatchMatchOptions, row_cache_bytes

_MIB = 1 << 20
_MAX_CACHED_VIEWS = 64  # Scene's image lru_cache
_FUSION_CHUNK = 1 << 16  # points of the output chunk (engine.fusion.cached.CHUNK_POINTS): 55 B + 43 B of records
_EVALUATION_CHUNK = 1 << 19  # points of the evaluation's chunk and slab (engine.evaluation.chunked): ~120 B each


@dataclasses.dataclass
class MemoryEstimate:
    """Bytes. ``peak`` = ``baseline`` + the largest of the stage increments."""

    baseline: int
    inputs: int
    patchmatch: int
    after_patchmatch: int
    available: int | None  # MemAvailable + baseline, or None when unknown

    @property
    def peak(self) -> int:
        return self.baseline + self.inputs + max(self.patchmatch, self.after_patchmatch)

    @property
    def fits(self) -> bool:
        return self.available is None or self.peak <= self.available

    def to_dict(self) -> dict[str, Any]:
        return {"baseline_mb": self.baseline / _MIB, "inputs_mb": self.inputs / _MIB,
                "patchmatch_mb": self.patchmatch / _MIB, "after_patchmatch_mb": self.after_patchmatch / _MIB,
                "estimated_peak_mb": self.peak / _MIB,
                "available_mb": None if self.available is None else self.available / _MIB}

    def summary(self) -> str:
        avail = "unknown" if self.available is None else f"{self.available / _MIB:,.0f} MiB"
        return (f"memory: estimated peak {self.peak / _MIB:,.0f} MiB (now {self.baseline / _MIB:,.0f}, inputs "
                f"+{self.inputs / _MIB:,.0f}, PatchMatch +{self.patchmatch / _MIB:,.0f}, fusion/evaluation "
                f"+{self.after_patchmatch / _MIB:,.0f}); available {avail}")


def current_rss() -> int:
    """Resident memory of this process in bytes (0 where /proc is missing)."""
    try:
        resident = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):
        return 0
    return resident * os.sysconf("SC_PAGE_SIZE")


def available_memory() -> int | None:
    """MemAvailable from /proc/meminfo in bytes, or None."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _ply_vertex_count(path: Path | None) -> int:
    if path is None:
        return 0
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError:
        return 0
    for line in head.split(b"\n"):
        words = line.split()
        if len(words) == 3 and words[0] == b"element" and words[1] == b"vertex" and words[2].isdigit():
            return int(words[2])
    return 0


def estimate_run_memory(scene: Any, options: Any, max_image_size: int | None = None,
                        baseline: int | None = None, available: int | None = -1) -> MemoryEstimate:
    """Estimate the peak resident memory of ``run_pipeline(scene, ..., options)``.

    Args:
        scene: a loaded :class:`engine.scene.Scene` (its working sizes are used unless ``max_image_size``
            asks what another size would need).
        options: :class:`engine.run.pipeline.PipelineOptions`.
        baseline: resident bytes now (default: measured).
        available: bytes the run may use on top of what it holds (default: MemAvailable).
    """
    pm = options.patchmatch
    sizes = []
    for v in scene.views:
        if max_image_size is None:
            sizes.append((v.camera.width, v.camera.height))
        else:
            sizes.append(rescaled_size(*v.original_size, max_image_size))
    pixels = [w * h for w, h in sizes]
    total = sum(pixels)
    largest = max(pixels)
    original_largest = max(w * h for w, h in (v.original_size for v in scene.views))
    sources = max((len(v.source_views) for v in scene.views), default=0)

    cached = sum(sorted(pixels, reverse=True)[:_MAX_CACHED_VIEWS])
    inputs = 4 * total + 27 * original_largest
    colour = 12 * cached  # the RGB cache, filled again after PatchMatch
    # the window's mean and variance, its choice, padded source images and source depths (the weights themselves
    # are computed per pixel visit: ncc.load_window)
    per_view_context = (4 * (2 + 2 * sources) + 1) * largest
    patchmatch = (4 * 4 // 3 + 4 + 4 + 6) * total + per_view_context + (3 * 24 + 20) * largest
    # the view being processed keeps per-pass cost caches (ViewState.prepare_caches): current
    # hypothesis costs (float32 per source), change stamps, active-set flags and, below ROW_CACHE_MAX_BYTES,
    # the candidate rows
    rows = row_cache_bytes(largest, 1, pm.k_update, sources)
    patchmatch += (4 * sources + 5) * largest + (rows if rows <= ROW_CACHE_MAX_BYTES else 0)
    gt_points = _ply_vertex_count(getattr(scene, "gt_points_path", None))
    fusion = 23 * total + 98 * min(total, _FUSION_CHUNK)  # at most a point a pixel
    # the GT points' index; then the GT views packed (4 B/px) and a chunk, or the GT points' voxels
    evaluation = 44 * gt_points + max(4 * total + 120 * min(total, _EVALUATION_CHUNK), 44 * gt_points)
    after = (24 + 1) * total + max(colour + fusion, evaluation)
    baseline = current_rss() if baseline is None else baseline
    if available == -1:
        free = available_memory()
        available = None if free is None else free + baseline
    return MemoryEstimate(baseline, inputs, patchmatch, after, available)


def largest_fitting_size(scene: Any, options: Any, estimate: MemoryEstimate) -> int | None:
    """The largest ``--max-image-size`` (a multiple of 32) whose estimate fits, or None if none does."""
    longest = max(max(v.original_size) for v in scene.views)
    size = (longest // 32) * 32
    while size >= 64:
        trial = estimate_run_memory(scene, options, size, estimate.baseline, None)
        if estimate.available is None or trial.peak <= estimate.available:
            return size
        size -= 32
    return None


def load_kernels() -> None:
    """Run PatchMatch once on two synthetic 24x24 views, so the kernels and the JIT runtime are resident."""
    from engine.patchmatch.multiscale import PatchMatchView, run_patchmatch  # lazy: numba (not for deepc info)

    rng = np.random.default_rng(0)
    views = []
    for i in range(2):
        camera = Camera.from_params(24, 24, 20.0, 20.0, 12.0, 12.0, np.eye(3), np.array([0.1 * i, 0.0, 0.0]))
        views.append(PatchMatchView(f"warm-up-{i}", rng.random((24, 24), dtype=np.float32), camera, 1.0, 3.0,
                                    [1 - i]))
    run_patchmatch(views, PatchMatchOptions(levels=1, geom_passes=1, iterations=1))
