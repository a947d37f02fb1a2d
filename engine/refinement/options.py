"""Options of the confidence-guided depth refinement (paper Sec. 4.2: Rossi et al., CVPR 2020)."""

from __future__ import annotations

import dataclasses

from engine.core.options import Options, check, option
from engine.refinement.sky import SkyOptions

SOLVERS = ("adam", "fast")
HOLE_INITS = ("nearest", "far")


@dataclasses.dataclass
class RefinementOptions(Options):
    """Energy, graph and solver settings; defaults = Rossi et al.'s README set, which DeepC uses.

    Per-scale lists run coarse -> fine and have one entry per scale.
    """

    # --- multi-scale solver
    scales: int = option(4, "pyramid scales, each half the size of the next; refined coarse to fine", source="Rossi",
                         low=1, high=8, metavar="N")
    solver: str = option("fast", "adam: Rossi et al.'s formulation (PyTorch Adam, slow); fast: primal-dual, same "
                         "energy", source="ours", choices=SOLVERS)
    iters: tuple[int, ...] = option((4000, 3000, 2000, 1000), "Adam iterations per scale, coarse to fine",
                                    source="Rossi", low=0, cli=False)
    lr: tuple[float, ...] = option((1e-2, 1e-2, 1e-3, 1e-4), "Adam start learning rate per scale", source="Rossi",
                                   above=0, cli=False)
    lr_slots: tuple[int, ...] = option((3, 3, 2, 1), "Adam learning-rate slots per scale (x0.1 per slot)",
                                       source="Rossi", low=1, cli=False)
    fast_iters: tuple[int, ...] = option((600, 400, 250, 120), "primal-dual iterations per scale, coarse to fine",
                                         source="ours", low=0, cli=False)
    fast_balance: float = option(0.05, "primal-dual step balance θ / median input inverse depth (speed only)",
                                 source="ours", above=0, cli=False)
    hole_init: str = option("nearest", "initial depth of pixels without data: nearest valid depth or the far plane "
                            "(Rossi)", source="ours", choices=HOLE_INITS)
    # --- energy
    lambda_data: float = option(1.0, "weight of the confidence-weighted L1 data term", source="Rossi", above=0,
                                metavar="W")
    lambda_reg: float = option(7.5, "weight of the piece-wise planar regulariser", source="Rossi", above=0,
                               metavar="W")
    gamma: float = option(5.5, "weight of the plane-orientation TV inside the regulariser", source="Rossi", low=0,
                          metavar="W")
    confidence_threshold: float | None = option(None, "binarise the data weights at this confidence (Rossi's example: "
                                                "0.5); unset = continuous", source="paper", low=0, high=1,
                                                metavar="T")
    backfacing_rule: bool = option(False, "weight the data term by the confidence after confidence.zero_backfacing "
                                   "(off: before)", source="ours")
    # --- similarity graph
    window: int = option(9, "similarity-graph search window (odd)", unit="px", source="Rossi", odd=True, low=3,
                         metavar="PX")
    patch: int = option(3, "similarity-graph patch size (odd)", unit="px", source="Rossi", odd=True, low=1,
                        metavar="PX")
    sigma_int: float = option(0.07, "graph intensity sigma", unit="grey on [0, 1]", source="Rossi", above=0,
                              metavar="S")
    sigma_spa: float = option(3.0, "graph spatial sigma", unit="px", source="Rossi", above=0, metavar="PX")
    degree: int = option(20, "neighbours kept per pixel (< window²)", source="Rossi", low=1, metavar="K")
    # --- full pipeline: what is fused after the refinement
    refined_confidence_tau: float = option(0.05, "keep fused pixels whose confidence (second network on the refined "
                                           "maps) is at least this", source="paper", low=0, high=1,
                                           aliases=("refined_conf_tau",), metavar="TAU")
    sky_filter: bool = option(True, "drop sky and far-plane pixels of refined maps (paper Sec. 5.5)", source="paper")
    keep_confident: float | None = option(0.1, "fuse PatchMatch's estimate where network 1's confidence is at least "
                                          "this; unset = the paper", source="ours", low=0, high=1, metavar="C")
    sky: SkyOptions = option(SkyOptions(), "the sky filter's mask and far-plane cut (with sky_filter)", cli=False)

    def validate(self) -> RefinementOptions:
        super().validate()
        for name in ("iters", "lr", "lr_slots", "fast_iters"):
            value = getattr(self, name)
            check(len(value) == self.scales, name, value, f"needs one entry per scale ({self.scales})")
        check(self.degree <= self.window * self.window - 1, "degree", self.degree, "must be in 1..window*window-1")
        return self
