"""What the rerun stream logs (``StreamOptions``): its own module so that flags and suites read it without rerun."""

from __future__ import annotations

import dataclasses

from engine.options import Options, option


@dataclasses.dataclass
class StreamOptions(Options):
    """What the rerun stream logs (thinning keeps recordings small)."""

    every: int = option(1, "log every k-th red-black iteration (the last one of each pass always)", source="ours",
                        low=1)
    view: int | None = option(None, "log the per-iteration maps of this view index only; unset = all views",
                              source="ours", low=0)
    max_size: int = option(0, "downscale logged maps to this longer side (0 = full size)", unit="px", source="ours",
                           low=0)
    selected_views_mask: bool = option(True, "log the raw selected-views bitmask (uint32) as well as the count",
                                       source="ours")
