"""Options of the confidence stage (kept free of torch so that importing the pipeline stays cheap)."""

from __future__ import annotations

import dataclasses

from engine.options import Options, check, option

LOSSES = ("deepc_squared", "deepc_l2", "bce", "wbce")
FUSIONS = ("middle", "early")
DEVICES = ("auto", "cpu", "cuda")


@dataclasses.dataclass
class ConfidenceOptions(Options):
    """Confidence stage of ``--pipeline fast`` (SPEC.md §4, §5, §12 ``filter``)."""

    tau: float = option(0.1, "keep pixels whose confidence is at least this before fusion (paper: 0.05-0.5; "
                        "ours, docs/decisions.md)", metavar="TAU")
    weights: str = option("", "weights file (default: the shipped engine/confidence/weights/deepc_middle.pt)",
                          metavar="FILE")
    refined_weights: str = option("", "weights for the confidence of refined maps (full pipeline; default: the "
                                  "shipped engine/confidence/weights/deepc_refined.pt, trained on refined maps)",
                                  metavar="FILE")
    tile: int = option(512, "largest tile side for inference in pixels, multiple of 16 (bounds memory)",
                       metavar="PX")
    overlap: int = option(64, "context pixels on each side of a tile", metavar="PX")
    bf16: bool = option(True, "bfloat16 autocast on CPUs that support it (faster, half the memory)")
    zero_backfacing: bool = option(False, "confidence 0 where the estimated normal faces away from the camera "
                                   "(ours, off by default: docs/decisions.md)")
    num_threads: int = option(0, "torch threads (0 = torch's default)", metavar="N")

    def validate(self) -> ConfidenceOptions:
        super().validate()
        check(0.0 <= self.tau <= 1.0, "tau", self.tau, "must be in [0, 1]")
        check(self.tile >= 64 and self.tile % 16 == 0, "tile", self.tile, "must be a multiple of 16, at least 64")
        check(0 <= self.overlap < self.tile // 2, "overlap", self.overlap, "must be in [0, tile/2)")
        check(self.num_threads >= 0, "num_threads", self.num_threads, "must be >= 0")
        return self


@dataclasses.dataclass
class TrainOptions(Options):
    """Options of ``deepc train`` (SPEC.md §12 ``confnet``)."""

    loss: str = option("deepc_squared", "training loss", choices=LOSSES)
    fusion: str = option("middle", "middle: one encoder per stream (paper); early: one encoder on 6 channels",
                         choices=FUSIONS)
    base_width: int = option(32, "channels of the first U-Net level, doubled per level (paper: 32)", metavar="N")
    epochs: int = option(20, "epochs", metavar="N")
    steps_per_epoch: int = option(40, "optimiser steps per epoch", metavar="N")
    batch: int = option(4, "crops per step", metavar="N")
    crop: int = option(192, "crop side in pixels (multiple of 16; clamped to the smallest image)", metavar="PX")
    min_labelled: float = option(0.05, "reject crops with a smaller fraction of labelled pixels", metavar="F")
    lr: float = option(1e-3, "initial Adam learning rate", metavar="LR")
    lr_final: float = option(1e-4, "learning rate at the end (cosine decay)", metavar="LR")
    flip: bool = option(True, "random horizontal flips (n_x negated)")
    normal_noise: float = option(0.3, "per crop, perturb the normals by Gaussian noise of a random size up to this "
                                 "(unit-vector units): PatchMatch normals of real, curved surfaces are much noisier "
                                 "than those of the piecewise-planar synthetic scenes (0 = off)", metavar="S")
    color_jitter: float = option(0.2, "random per-crop RGB gain/bias of this size (photometric augmentation for "
                                 "the transfer to photographs; 0 = off)", metavar="S")
    bf16: bool = option(True, "bfloat16 autocast for the forward pass (about 2x faster on AVX-512 CPUs)")
    seed: int = option(0, "seed of initialisation and crop sampling", metavar="N")
    num_threads: int = option(0, "torch threads (0 = torch's default)", metavar="N")
    device: str = option("auto", "where to train: auto (a CUDA GPU when present), cpu or cuda", choices=DEVICES)

    def validate(self) -> TrainOptions:
        super().validate()
        for name in ("epochs", "steps_per_epoch", "batch"):
            check(getattr(self, name) >= 1, name, getattr(self, name), "must be >= 1")
        check(self.crop >= 32 and self.crop % 16 == 0, "crop", self.crop, "must be a multiple of 16, at least 32")
        check(1 <= self.base_width <= 256, "base_width", self.base_width, "must be in 1..256")
        check(0.0 <= self.normal_noise <= 2.0, "normal_noise", self.normal_noise, "must be in [0, 2]")
        check(0.0 <= self.color_jitter < 1.0, "color_jitter", self.color_jitter, "must be in [0, 1)")
        check(0.0 <= self.min_labelled < 1.0, "min_labelled", self.min_labelled, "must be in [0, 1)")
        check(self.lr > 0 and self.lr_final > 0, "lr", self.lr, "learning rates must be positive")
        return self
