"""Options of the confidence stage (kept free of torch so that importing the pipeline stays cheap)."""

from __future__ import annotations

import dataclasses

from engine.options import Options, check, option


@dataclasses.dataclass
class ConfidenceOptions(Options):
    """Confidence stage of ``--pipeline fast`` (SPEC.md §4, §5, §12 ``filter``)."""

    tau: float = option(0.05, "keep pixels whose confidence is at least this before fusion", metavar="TAU")
    weights: str = option("", "weights file (default: the shipped engine/confidence/weights/deepc_middle.pt)",
                          metavar="FILE")
    refined_weights: str = option("", "weights for the confidence of refined maps (full pipeline; default: the "
                                  "same weights as --weights until a network trained on refined maps ships)",
                                  metavar="FILE")
    tile: int = option(512, "largest tile side for inference, multiple of 16 (bounds memory; 512 is also the "
                       "fastest on 2 cores)", metavar="PX")
    overlap: int = option(64, "context pixels on each side of a tile", metavar="PX")
    bf16: bool = option(True, "bfloat16 autocast on CPUs that support it (faster, half the memory)")
    zero_backfacing: bool = option(True, "confidence 0 where the estimated normal faces away from the camera "
                                   "(an unobservable surface: the counter map's front-facing check, applied to "
                                   "the network output)")
    num_threads: int = option(0, "torch threads (0 = torch's default)", metavar="N")

    def validate(self) -> ConfidenceOptions:
        super().validate()
        check(0.0 <= self.tau <= 1.0, "tau", self.tau, "must be in [0, 1]")
        check(self.tile >= 64 and self.tile % 16 == 0, "tile", self.tile, "must be a multiple of 16, at least 64")
        check(0 <= self.overlap < self.tile // 2, "overlap", self.overlap, "must be in [0, tile/2)")
        check(self.num_threads >= 0, "num_threads", self.num_threads, "must be >= 0")
        return self
