"""The size of a run's recording, planned before PatchMatch starts: the largest logged map size that keeps the
recording within ``StreamOptions.budget_mb``.

A recording is mostly per-iteration maps (depth as a 16-bit PNG, normals as a JPEG, class-coded maps compressed by
rerun), so its size follows the map pixels it logs: every logged iteration of every view at every pyramid level.
Maps are downscaled by whole steps (``workbench.maps.images.subsample``), so the sizes to choose from are the
finest level's longer side divided by 1, 2, 3, ...; coarse levels already below the size are logged whole.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: compressed bytes per logged map pixel and iteration, all maps of a view together (depth, normal, cost, selected
#: views, GT error, and counter / confidence / labels every third iteration), and per logged view iteration whatever
#: its size (image headers, scalars, rerun's rows), fitted on the demo's recording (sample_scenes/small, ACMM
#: schedule, live confidence: benchmarks/results/bench_recording.json): the estimate is within 1 % of the stream as
#: logged, which is what a live viewer receives; the finished file is compacted (``workbench.rerun.recording.compact``),
#: about 29 % smaller, so the budget bounds the file with room to spare
BYTES_PER_PIXEL_ITERATION, BYTES_PER_VIEW_ITERATION = 5.5, 12_000.0
#: compressed bytes per fused point logged (xyz float32, rgba) and per photograph pixel (a JPEG), the same way
BYTES_PER_POINT, BYTES_PER_PHOTO_PIXEL = 15.0, 0.45


def level_pixels(width: int, height: int, level: int, max_size: int) -> int:
    """Pixels of a map of pyramid ``level`` of a ``width`` × ``height`` view once subsampled to ``max_size``
    (0 = whole), as ``workbench.maps.images.subsample`` and ``engine.patchmatch.pyramid.level_size`` make them."""
    s = 0.5**level
    w, h = max(1, int(round(width * s))), max(1, int(round(height * s)))
    step = max(1, math.ceil(max(w, h) / max_size)) if max_size > 0 else 1
    return math.ceil(w / step) * math.ceil(h / step)


def logged_iterations(pass_iterations: Sequence[int], every: int) -> int:
    """Iterations of one view at one level that a stream logging every ``every``-th keeps (and the last of each
    pass), for passes of ``pass_iterations`` iterations."""
    return sum(len({i for i in range(n) if i % every == 0} | {n - 1}) for n in pass_iterations if n > 0)


def planned_bytes(sizes: Sequence[tuple[int, int]], levels: int, iterations_per_level: int, max_size: int,
                  max_points: int) -> float:
    """Estimated bytes of a recording of views of ``sizes`` (width, height) over ``levels`` pyramid levels of
    ``iterations_per_level`` logged iterations each, maps at ``max_size``, and a cloud of at most ``max_points``
    (and at most a point per pixel: fusion makes one point of one or more pixels)."""
    pixels = sum(level_pixels(w, h, level, max_size) for w, h in sizes for level in range(levels))
    photos = sum(w * h for w, h in sizes)
    maps = iterations_per_level * (BYTES_PER_PIXEL_ITERATION * pixels + BYTES_PER_VIEW_ITERATION * len(sizes) * levels)
    return maps + BYTES_PER_PHOTO_PIXEL * photos + BYTES_PER_POINT * min(max_points, photos)


#: how far maps are downscaled (whole steps of the finest level) before iterations are thinned instead: a map at
#: half size still shows what went wrong where; past that, fewer sharp iterations read better than blurred ones
STEP_BEFORE_THINNING = 2
MAX_EVERY, MAX_STEP = 8, 16


def budget_plan(sizes: Sequence[tuple[int, int]], levels: int, pass_iterations: Sequence[int], budget_mb: float,
                max_points: int, max_size: int | None = None, every: int | None = None) -> tuple[int, int]:
    """(map size: longer side in px, 0 = whole; log every k-th iteration) for a recording of views of ``sizes`` over
    ``levels`` pyramid levels of passes of ``pass_iterations`` iterations within ``budget_mb`` megabytes (0 = no
    bound). A ``max_size`` or ``every`` given is kept; the rest is chosen in this order of preference: whole maps of
    every iteration, maps downscaled by up to ``STEP_BEFORE_THINNING``, every k-th iteration (up to ``MAX_EVERY``),
    then smaller maps (up to ``MAX_STEP``). When nothing fits, the smallest plan tried."""
    longest = max((max(w, h) for w, h in sizes), default=0)

    def size_of(step: int) -> int:
        return 0 if step == 1 else math.ceil(longest / step)

    if max_size is None:
        plans = [(size_of(s), 1) for s in range(1, STEP_BEFORE_THINNING + 1)]
        plans += [(size_of(STEP_BEFORE_THINNING), k) for k in range(2, MAX_EVERY + 1)]
        plans += [(size_of(s), MAX_EVERY) for s in range(STEP_BEFORE_THINNING + 1, MAX_STEP + 1)]
    else:
        plans = [(max_size, k) for k in range(1, MAX_EVERY + 1)]
    if every is not None:
        plans = list(dict.fromkeys((size, every) for size, _ in plans))
    if budget_mb <= 0 or not sizes:
        return plans[0]
    for size, k in plans:
        if planned_bytes(sizes, levels, logged_iterations(pass_iterations, k), size, max_points) <= budget_mb * 1e6:
            return size, k
    return plans[-1]
