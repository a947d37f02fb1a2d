"""The DeepC confidence U-Net (Kuhn et al. 2020, §3.2).

Middle fusion (the paper's design): three encoders with identical structure and separate weights,
one per input stream (RGB 3, normal 2, counter 1 channels). Each of the 4 encoder blocks is two
Conv3×3-BN-ReLU sub-blocks (widths 32, 64, 128, 256) followed by MaxPool 2×2; the skip of level k is
the concatenation of the three streams' pre-pool features, the bottleneck the concatenation of their
last pooled features (768 @ H/16). Decoder: per level bilinear ×2 up-sampling, concatenation with the
skip and one Conv3×3-BN-ReLU; head Conv3×3 (32 → 1) and sigmoid. Early fusion (ablation): one encoder
on the 6 concatenated channels, same decoder. The network returns logits; c = sigmoid(logits).
Input H and W must be multiples of 16 (see :func:`pad_to_multiple`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from engine.confidence.options import FUSIONS

STREAMS = {"rgb": (0, 3), "normal": (3, 5), "counter": (5, 6)}
DEFAULT_WIDTHS = (32, 64, 128, 256)


def conv_bn_relu(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out),
                         nn.ReLU(inplace=True))


class Encoder(nn.Module):
    """4 blocks of (Conv-BN-ReLU)×2; returns the pre-pool features of each block and the last pooled one."""

    def __init__(self, c_in: int, widths: tuple[int, ...]):
        super().__init__()
        blocks, c = [], c_in
        for w in widths:
            blocks.append(nn.Sequential(conv_bn_relu(c, w), conv_bn_relu(w, w)))
            c = w
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        skips = []
        for block in self.blocks:
            x = block(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        return skips, x


class ConfidenceNet(nn.Module):
    """(B, 6, H, W) inputs -> (B, 1, H, W) logits."""

    def __init__(self, fusion: str = "middle", widths: tuple[int, ...] = DEFAULT_WIDTHS):
        super().__init__()
        if fusion not in FUSIONS:
            raise ValueError(f"fusion must be one of {FUSIONS}, got {fusion!r}")
        self.fusion, self.widths = fusion, tuple(int(w) for w in widths)
        if fusion == "middle":
            self.encoders = nn.ModuleDict({name: Encoder(hi - lo, self.widths) for name, (lo, hi) in STREAMS.items()})
            streams = len(STREAMS)
        else:
            self.encoders = nn.ModuleDict({"all": Encoder(6, self.widths)})
            streams = 1
        decoder, c = [], streams * self.widths[-1]
        for w in reversed(self.widths):
            decoder.append(conv_bn_relu(c + streams * w, w))
            c = w
        self.decoder = nn.ModuleList(decoder)
        self.head = nn.Conv2d(self.widths[0], 1, 3, padding=1)

    @property
    def architecture(self) -> dict:
        """What must match for weights to load."""
        return {"name": "deepc_unet", "fusion": self.fusion, "widths": list(self.widths)}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.fusion == "middle":
            outs = [self.encoders[name](x[:, lo:hi]) for name, (lo, hi) in STREAMS.items()]
            skips = [torch.cat([o[0][k] for o in outs], 1) for k in range(len(self.widths))]
            y = torch.cat([o[1] for o in outs], 1)
        else:
            skips, y = self.encoders["all"](x)
        for conv, skip in zip(self.decoder, reversed(skips), strict=True):
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = conv(torch.cat([y, skip], 1))
        return self.head(y)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def pad_to_multiple(x: torch.Tensor, multiple: int = 16) -> tuple[torch.Tensor, tuple[int, int]]:
    """Reflect-pad (B, C, H, W) at the bottom/right to multiples of ``multiple``; returns the original (H, W)."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        mode = "reflect" if ph < h and pw < w else "replicate"
        x = F.pad(x, (0, pw, 0, ph), mode=mode)
    return x, (h, w)
