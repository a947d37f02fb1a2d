"""What the rerun stream logs (``StreamOptions``): its own module so that flags and suites read it without rerun."""

from __future__ import annotations

import dataclasses

from engine.core.options import Options, option

#: ``confidence_every`` of a live stream when none is given: the smallest k whose scoring costs at most 25 % of
#: PatchMatch's time in the demo (scripts/demo.sh; measured in docs/decisions.md, "Confidence while PatchMatch runs")
DEFAULT_CONFIDENCE_EVERY = 3


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
    confidence_every: int | None = option(
        None, f"score counter and confidence every k-th iteration of a view; unset = {DEFAULT_CONFIDENCE_EVERY} live, "
        "off headless; 0 = off", source="ours", low=0, metavar="K")

    def confidence_k(self, live: bool) -> int:
        """The k of :attr:`confidence_every` for a stream to a live viewer (``live``) or to a file only: as given,
        else :data:`DEFAULT_CONFIDENCE_EVERY` live and 0 (off) without a viewer."""
        if self.confidence_every is not None:
            return self.confidence_every
        return DEFAULT_CONFIDENCE_EVERY if live else 0
