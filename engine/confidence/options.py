"""Options of the confidence stage (kept free of torch so that importing the pipeline stays cheap)."""

from __future__ import annotations

import dataclasses

from engine.core.options import Options, check, option

LOSSES = ("deepc_squared", "deepc_l2", "bce", "wbce")
FUSIONS = ("middle", "early")
DEVICES = ("auto", "cpu", "cuda")


@dataclasses.dataclass
class ConfidenceOptions(Options):
    """Confidence stage of ``--pipeline fast`` and ``full``: the network (paper Sec. 3.2) and its filter (Sec. 4.1)."""

    tau: float = option(0.1, "keep pixels whose confidence is at least this before fusion (paper: 0.05)",
                        source="ours", low=0, high=1, metavar="TAU")
    weights: str = option("", "weights file; empty = the shipped engine/confidence/weights/deepc_middle.pt",
                          source="ours", metavar="FILE")
    refined_weights: str = option("", "weights for refined maps (full); empty = the shipped deepc_refined.pt",
                                  source="ours", metavar="FILE")
    tile: int = option(512, "largest tile side for inference (bounds memory)", unit="px", source="ours",
                       multiple_of=16, low=64, metavar="PX")
    overlap: int = option(64, "context on each side of a tile (< tile/2)", unit="px", source="ours", low=0,
                          metavar="PX")
    bf16: bool = option(True, "bfloat16 autocast on CPUs that support it (faster, half the memory)", source="ours")
    zero_backfacing: bool = option(False, "confidence 0 where the normal faces away from the camera (our rule; off = "
                                   "the paper)", source="paper")
    num_threads: int = option(0, "torch threads (0 = torch's default)", source="ours", low=0, metavar="N")

    def validate(self) -> ConfidenceOptions:
        super().validate()
        check(self.overlap < self.tile // 2, "overlap", self.overlap, "must be in [0, tile/2)")
        return self


@dataclasses.dataclass
class TrainOptions(Options):
    """Options of ``deepc train`` (paper Sec. 5.2); the shipped networks' recipes override some of them."""

    loss: str = option("deepc_squared", "training loss", source="paper", choices=LOSSES)
    fusion: str = option("middle", "middle: one encoder per stream (paper); early: one encoder on 6 channels",
                         source="paper", choices=FUSIONS)
    base_width: int = option(32, "channels of the first U-Net level, doubled per level", source="paper", low=1,
                             high=256, metavar="N")
    epochs: int = option(20, "epochs (paper: 100)", source="ours", low=1, metavar="N")
    steps_per_epoch: int = option(40, "optimiser steps per epoch", source="ours", low=1, metavar="N")
    batch: int = option(4, "crops per step", source="ours", low=1, metavar="N")
    crop: int = option(192, "crop side (clamped to the smallest image)", unit="px", source="ours", multiple_of=16,
                       low=32, metavar="PX")
    min_labelled: float = option(0.05, "reject crops with a smaller fraction of labelled pixels", source="ours",
                                 low=0, below=1, metavar="F")
    lr: float = option(1e-3, "initial Adam learning rate", source="ours", above=0, metavar="LR")
    lr_final: float = option(1e-4, "learning rate at the end of the cosine decay", source="ours", above=0,
                             metavar="LR")
    flip: bool = option(True, "random horizontal flips (n_x negated)", source="ours")
    normal_noise: float = option(0.3, "largest Gaussian noise added to a crop's normals (0 = off)",
                                 unit="unit-vector units", source="ours", low=0, high=2, metavar="S")
    color_jitter: float = option(0.2, "largest random per-crop RGB gain/bias (0 = off)", source="ours", low=0,
                                 below=1, metavar="S")
    bf16: bool = option(True, "bfloat16 autocast for the forward pass (about 2x faster on AVX-512 CPUs)",
                        source="ours")
    seed: int = option(0, "seed of initialisation and crop sampling", source="ours", metavar="N")
    num_threads: int = option(0, "torch threads (0 = torch's default)", source="ours", low=0, metavar="N")
    device: str = option("auto", "where to train: auto (a CUDA GPU when present), cpu or cuda", source="ours",
                         choices=DEVICES)
