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

    every: int | None = option(None, "log every k-th red-black iteration (and each pass's last); unset = as budget_mb "
                               "allows", source="ours", low=1)
    view: int | None = option(None, "log the per-iteration maps of this view index only; unset = all views",
                              source="ours", low=0)
    max_size: int | None = option(None, "downscale logged maps to this longer side; unset = as budget_mb allows; "
                                  "0 = full size", unit="px", source="ours", low=0)
    budget_mb: float = option(15.0, "size of a run's recording, where max_size or every is unset (0 = no bound)",
                              unit="MB", source="ours", low=0)
    selected_views_mask: bool = option(True, "log the raw selected-views bitmask as well as the count",
                                       source="ours")
    max_points: int = option(100_000, "log every k-th point of a fused cloud above this many (0 = all)",
                             unit="points", source="ours", low=0)
    confidence_every: int | None = option(
        None, f"score counter and confidence every k-th iteration of a view; unset = {DEFAULT_CONFIDENCE_EVERY} live, "
        "off headless; 0 = off", source="ours", low=0, metavar="K")

    def confidence_k(self, live: bool) -> int:
        """The k of :attr:`confidence_every` for a stream to a live viewer (``live``) or to a file only: as given,
        else :data:`DEFAULT_CONFIDENCE_EVERY` live and 0 (off) without a viewer."""
        if self.confidence_every is not None:
            return self.confidence_every
        return DEFAULT_CONFIDENCE_EVERY if live else 0
