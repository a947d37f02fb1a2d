"""Options of the confidence-guided depth refinement (SPEC.md §6, §12 ``refine``)."""

from __future__ import annotations

import dataclasses

from engine.options import Options, check, option

SOLVERS = ("adam", "fast")
HOLE_INITS = ("nearest", "far")


@dataclasses.dataclass
class RefinementOptions(Options):
    """Energy, graph and solver settings; defaults = Rossi et al.'s README set used by DeepC.

    Per-scale lists run coarse -> fine and have one entry per scale.
    """

    scales: int = option(4, "pyramid scales (each halves the size); processed coarse to fine", metavar="N")
    solver: str = option("fast", "adam: official formulation (PyTorch Adam, slow reference); "
                         "fast: preconditioned primal-dual (numba) on the same energy", choices=SOLVERS)
    iters: tuple[int, ...] = option((4000, 3000, 2000, 1000), "Adam iterations per scale, coarse to fine",
                                    cli=False)
    lr: tuple[float, ...] = option((1e-2, 1e-2, 1e-3, 1e-4), "Adam start learning rate per scale", cli=False)
    lr_slots: tuple[int, ...] = option((3, 3, 2, 1), "Adam learning-rate slots per scale (x0.1 per slot)",
                                       cli=False)
    # (300, 300, 250, 500) converges further at the finest scale (small scene: planar-normal error 3.7° vs
    # 5.3° mean) for 2.7x the CPU time (105 vs 39 CPU-s per 768x512 map); see benchmarks/results.
    fast_iters: tuple[int, ...] = option((600, 400, 250, 120), "primal-dual iterations per scale, coarse to fine",
                                         cli=False)
    fast_balance: float = option(0.05, "primal-dual step balance θ / median input inverse depth (speed only)",
                                 cli=False)
    lambda_data: float = option(1.0, "weight of the confidence-weighted L1 data term", metavar="W")
    lambda_reg: float = option(7.5, "weight of the piece-wise planar regulariser", metavar="W")
    gamma: float = option(5.5, "weight of the plane-orientation TV inside the regulariser", metavar="W")
    window: int = option(9, "similarity-graph search window (odd)", metavar="PX")
    patch: int = option(3, "similarity-graph patch size (odd)", metavar="PX")
    sigma_int: float = option(0.07, "graph intensity sigma (grey in [0,1])", metavar="S")
    sigma_spa: float = option(3.0, "graph spatial sigma in pixels", metavar="PX")
    degree: int = option(20, "neighbours kept per pixel", metavar="K")
    confidence_threshold: float | None = option(
        None, "binarise the confidence at this value (the README example uses 0.5); unset = continuous",
        metavar="T")
    refined_conf_tau: float = option(0.05, "full pipeline: keep refined pixels whose confidence (second network) "
                                     "is at least this", metavar="TAU")
    sky_filter: bool = option(True, "full pipeline: drop sky and far-plane pixels of refined maps (SPEC §8)")
    keep_confident: float | None = option(0.1, "full pipeline: fuse the PatchMatch estimate where network 1's "
                                          "confidence is at least this, the refined one elsewhere (ours, "
                                          "docs/decisions.md; unset = the paper: refined everywhere)", metavar="C")
    backfacing_rule: bool = option(False, "weight the data term by the confidence after confidence.zero_backfacing "
                                   "(off: before it; zeroing those pixels left whole grazing planes without data and "
                                   "the regulariser carried the neighbouring planes onto them: fountain_p11 view 0 "
                                   "within 5 % 81.9 vs 90.7, planar normals 72.8 vs 10.1 degrees)")
    hole_init: str = option("nearest", "initial depth of pixels without data: nearest valid depth "
                            "(converges faster) or the far plane (official code)", choices=HOLE_INITS)

    def validate(self) -> RefinementOptions:
        super().validate()
        check(1 <= self.scales <= 8, "scales", self.scales, "must be in 1..8")
        for name in ("iters", "lr", "lr_slots", "fast_iters"):
            value = getattr(self, name)
            check(len(value) == self.scales, name, value, f"needs one entry per scale ({self.scales})")
        check(all(int(v) >= 0 for v in self.iters), "iters", self.iters, "must be >= 0")
        check(all(int(v) >= 0 for v in self.fast_iters), "fast_iters", self.fast_iters, "must be >= 0")
        check(all(v > 0 for v in self.lr), "lr", self.lr, "must be > 0")
        check(all(int(v) >= 1 for v in self.lr_slots), "lr_slots", self.lr_slots, "must be >= 1")
        check(self.fast_balance > 0, "fast_balance", self.fast_balance, "must be > 0")
        check(self.lambda_data > 0, "lambda_data", self.lambda_data, "must be > 0")
        check(self.lambda_reg > 0, "lambda_reg", self.lambda_reg, "must be > 0")
        check(self.gamma >= 0, "gamma", self.gamma, "must be >= 0")
        check(self.window >= 3 and self.window % 2 == 1, "window", self.window, "must be odd and >= 3")
        check(self.patch >= 1 and self.patch % 2 == 1, "patch", self.patch, "must be odd and >= 1")
        check(self.sigma_int > 0, "sigma_int", self.sigma_int, "must be > 0")
        check(self.sigma_spa > 0, "sigma_spa", self.sigma_spa, "must be > 0")
        check(1 <= self.degree <= self.window * self.window - 1, "degree", self.degree,
              "must be in 1..window*window-1")
        check(0.0 <= self.refined_conf_tau <= 1.0, "refined_conf_tau", self.refined_conf_tau, "must be in [0, 1]")
        if self.keep_confident is not None:
            check(0.0 <= self.keep_confident <= 1.0, "keep_confident", self.keep_confident, "must be in [0, 1]")
        if self.confidence_threshold is not None:
            check(0.0 <= self.confidence_threshold <= 1.0, "confidence_threshold", self.confidence_threshold,
                  "must be in [0, 1]")
        return self
