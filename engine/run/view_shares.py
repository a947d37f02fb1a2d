"""Per-view shares a user can judge without ground truth: how much of each view became fused points, and how much
of it another view confirms; views far below the others are named.

- ``fused_pct``: the view's pixels that became points of the fused cloud, in percent of its pixels: the points
  whose ``source_view`` is the view. With ``point_per_pixel`` (the ``pixels`` preset every pipeline fuses with)
  a point is one pixel of that view; with other presets a point counts for the view of its seed pixel.
- ``confirmed_pct``: the pixels whose PatchMatch estimate at least one source view confirms (counter map >= 1,
  ``engine.consistency``: the estimate agrees in >= 2 views, the view itself included), in percent of its pixels.

Both come from what a run has anyway (the cloud's per-point view, the counter maps), in memory or read view by
view from a run folder.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from engine.core.heap_trim import release_mapped_pages

#: a view whose fused share is under this fraction of the median view's is named in a warning
WEAK_SHARE = 0.5
_CHUNK = 1 << 18  # points counted at a time (a cloud on disk is read in pieces: 11 MiB of its records)


def points_per_view(source_view: np.ndarray, n_views: int) -> np.ndarray:
    """(n_views,) int64 number of points per ``source_view`` index, counted in chunks."""
    counts = np.zeros(n_views, np.int64)
    for start in range(0, len(source_view), _CHUNK):
        counts += np.bincount(np.asarray(source_view[start:start + _CHUNK], np.int64), minlength=n_views)[:n_views]
        release_mapped_pages(source_view)  # a cloud on disk: its records' pages were read once
    return counts


def view_shares(names: list[str], source_view: np.ndarray, counter_of: Callable[[int], np.ndarray]
                ) -> list[dict[str, Any]]:
    """Per view (in ``names`` order) ``{"view", "pixels", "fused_pct", "confirmed_pct"}`` (module doc);
    ``source_view`` is the fused cloud's, ``counter_of(i)`` view i's counter map at its working size."""
    fused = points_per_view(source_view, len(names))
    entries = []
    for i, name in enumerate(names):
        counter = counter_of(i)
        pixels = int(counter.size)
        confirmed = int(np.count_nonzero(counter >= 1))
        entries.append({"view": name, "pixels": pixels, "fused_pct": 100.0 * int(fused[i]) / max(1, pixels),
                        "confirmed_pct": 100.0 * confirmed / max(1, pixels)})
    return entries


def weak_views(entries: list[dict[str, Any]], share: float = WEAK_SHARE) -> tuple[list[dict[str, Any]], float]:
    """The entries whose ``fused_pct`` is under ``share`` × the median over the views, and that median."""
    if not entries:
        return [], 0.0
    median = float(np.median([e["fused_pct"] for e in entries]))
    return [e for e in entries if e["fused_pct"] < share * median], median


def view_share_lines(entries: list[dict[str, Any]]) -> tuple[list[str], list[str]]:
    """(summary lines, warning lines) of :func:`view_shares`' entries: one line per view, one warning per weak one."""
    width = min(28, max((len(e["view"]) for e in entries), default=4))
    lines = [f"view {e['view'][:28]:<{width}}  {e['fused_pct']:5.1f}% of pixels fused, "
             f"{e['confirmed_pct']:5.1f}% confirmed by >= 2 views" for e in entries]
    weak, median = weak_views(entries)
    warnings = [f"warning: view {e['view']}: {e['fused_pct']:.1f}% of its pixels fused, under "
                f"{WEAK_SHARE:g} x the median view's {median:.1f}% (few source views agree with it, or its "
                "estimates were filtered out)" for e in weak]
    return lines, warnings
