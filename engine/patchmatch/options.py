"""``PatchMatchOptions``: every PatchMatch setting, with the paper's defaults where it gives one.

Sources: the DeepC-MVS paper (Kuhn et al., 3DV 2020) and the ACMM and COLMAP code it builds on. Where a
default is ours instead, docs/decisions.md says why and names the benchmark behind it.
"""

from __future__ import annotations

import dataclasses

from engine.core.options import Options, check, option

SCHEDULES = ("paper", "acmm")
PATTERNS = ("deepc", "deepc_far", "acmm")
WEIGHTINGS = ("colmap", "acmm")
VIEW_SAMPLING = ("monte_carlo", "deterministic")
COMBOS = ("acmm5", "all8")
EPS_SCHEDULES = ("pass", "global")
RESTORER_REFERENCES = ("upsampled", "random")


@dataclasses.dataclass
class PatchMatchOptions(Options):
    """Multi-scale PatchMatch MVS: ACMM's backbone with the DeepC modifications."""

    # --- schedule: red-black iterations per pass, pyramid levels, passes per level
    schedule: str = option("paper", "iterations per pass: 'paper' = 8 in every pass, 'acmm' = 3 photometric / 2 "
                           "geometric", source="paper", choices=SCHEDULES)
    iterations: int | None = option(None, "this many red-black iterations in every pass; unset = the schedule's",
                                    source="ours", low=1)
    converge_ratio: float = option(0.8, "end a pass once an iteration's changed share exceeds this x the last "
                                   "one's; 0 = off", source="ours", low=0, below=1, absent=0.0)
    active_share: float = option(0.1, "from a pass's 3rd iteration update only pixels near moved ones, and this "
                                 "random share; -1 = off", source="ours", off=-1.0, low=0, high=1,
                                 absent=-1.0)
    converge_depth: float = option(0.01, "a pixel has changed (convergence, active set) when its depth moves more "
                                   "than this",
                                   unit="relative depth", source="ours", above=0)
    levels: int = option(3, "pyramid levels, factor 0.5 apart (fewer if the coarsest is below min_level_size)",
                         source="paper", low=1, high=8)
    min_level_size: int = option(16, "smallest shorter image side at the coarsest level", unit="px", source="ours",
                                 low=8)
    geom_passes: int = option(2, "geometric-consistency passes per level after the photometric pass",
                              source="ACMM", low=0, high=4)
    # --- matching cost: bilateral NCC over the standard window
    window: int = option(11, "matching window side (odd)", unit="px", source="ACMM", odd=True, low=3)
    window_step: int = option(2, "sampling step inside the window (2 = ACMM's 36 samples)", unit="px",
                              source="ACMM", low=1)
    sigma_spatial: float = option(5.0, "bilateral spatial sigma", unit="px", source="COLMAP", above=0)
    sigma_color: float = option(0.2, "bilateral colour sigma, 'colmap' weighting", unit="intensity on [0, 1]",
                                source="COLMAP", above=0)
    min_var: float = option(1e-5, "weighted variance below which a window is textureless (cost 2)",
                            unit="intensity² on [0, 1]", source="COLMAP", low=0)
    init_top_k: int = option(4, "initial cost = mean of the k best per-view costs", source="ACMM", low=1, high=32)
    # --- fine window: a small dense window near depth edges and creases, where the standard one straddles two
    # surfaces and fattens the foreground (docs/decisions.md)
    fine_window: int = option(5, "side of the fine window (odd); 0 = off, one window everywhere (paper)", unit="px",
                              source="ours", off=0, odd=True, low=3)
    fine_window_step: int = option(1, "sampling step inside the fine window", unit="px", source="ours", low=1)
    fine_sigma_spatial: float = option(1.5, "bilateral spatial sigma of the fine window", unit="px", source="ours",
                                       above=0)
    fine_sigma_color: float = option(0.05, "bilateral colour sigma of the fine window ('colmap' weighting)",
                                     unit="intensity on [0, 1]", source="ours", above=0)
    fine_min_var: float = option(1e-3, "a pixel uses the fine window when the variance under it reaches this",
                                 unit="intensity² on [0, 1]", source="ours", low=0)
    fine_max_level: int = option(0, "coarsest pyramid level that uses the fine window (0 = the finest only)",
                                 source="ours", low=0, high=7)
    fine_edge_radius: int = option(5, "use the fine window within this distance of an edge; 0 = wherever textured",
                                   unit="px", source="ours", low=0, high=32)
    fine_edge_jump: float = option(0.02, "neighbours whose planes predict each other's depth this far off are an edge",
                                   unit="relative depth", source="ours", above=0)
    fine_crease_angle: float = option(20.0, "neighbours whose normals differ by more are an edge too; 0 = depth edges "
                                      "only", unit="degrees", source="ours", low=0, below=90)
    fine_crease_min_var_ratio: float = option(0.1, "at a crease, fine-window variance needed / the standard window's",
                                              source="ours", low=0, high=1)
    # --- propagation and perturbation
    k_viewsel: int = option(8, "best samples whose costs drive view selection", source="paper", low=1, high=32)
    k_update: int = option(16, "best samples evaluated as update candidates (>= k_viewsel)", source="paper",
                           low=1, high=32)
    eps_schedule: str = option("global", "perturbation 2^-t: 'pass' = t restarts every pass (paper), 'global' = "
                               "t runs on", source="ours", choices=EPS_SCHEDULES)
    eps_min: float = option(2.0**-7, "smallest perturbation scale with eps_schedule 'global' (2^-7)",
                            source="ours", above=0, high=1)
    normal_perturb_retries: int = option(3, "retries with halved angle when a perturbed normal faces away",
                                         source="COLMAP", low=0, high=10)
    min_improvement: float = option(0.003, "cost decrease a new hypothesis needs, except in a pass's last "
                                    "iteration; 0 = any (ACMM)", unit="cost", source="ours", low=0)
    # --- view selection: ACMM's multi-hypothesis joint view selection
    mc_samples: int = option(15, "Monte-Carlo draws for the view weights", source="ACMM", low=1, high=1000)
    tau0: float = option(0.8, "good-cost threshold at iteration 0: tau_g(t) = tau0 exp(-t² / alpha)", unit="cost",
                         source="ACMM", above=0, high=2)
    alpha: float = option(0.0, "decay of the good-cost threshold over a pass; 0 = constant (ACMM: 90)",
                          unit="iterations²", source="ours", low=0)
    tau_bad: float = option(1.2, "bad-cost threshold", unit="cost", source="ACMM", above=0, high=2)
    beta: float = option(0.3, "width of the Gaussian turning good costs into view weights", unit="cost",
                         source="ACMM", above=0)
    beta_fallback: float = option(0.4, "width used for views with few good costs", unit="cost", source="ACMM",
                                  above=0)
    n_good_gt: int = option(2, "a view needs more than this many good costs for the full weight", source="ACMM",
                            low=0)
    n_bad_lt: int = option(3, "a view with this many bad costs gets weight 0", source="ACMM", low=1)
    prior_in: float = option(0.9, "neighbourhood prior of a view a 4-neighbour selected", source="ACMM", low=0)
    prior_out: float = option(0.1, "neighbourhood prior of a view no 4-neighbour selected", source="ACMM", low=0)
    # --- geometric consistency
    geom_lambda: float = option(0.2, "weight of the geometric term in geometric passes", source="ACMM", low=0)
    geom_max: float = option(3.0, "truncation of the forward-backward reprojection error", unit="px", source="ACMM",
                             above=0)
    # --- multi-scale: joint bilateral upsampling and the detail restorer
    detail_restorer: bool = option(True, "keep the upsampled hypothesis unless the new cost is much lower",
                                   source="paper")
    detail_restorer_delta: float = option(0.1, "detail restorer: required cost improvement", unit="cost",
                                          source="ACMM", low=0)
    detail_restorer_reference: str = option("random", "cost the restorer compares with: of the 'upsampled' plane or "
                                            "of a 'random' normal", source="ACMM", choices=RESTORER_REFERENCES)
    jbu_sigma_spatial: float = option(0.5, "JBU spatial sigma", unit="low-res px", source="ACMM", above=0)
    jbu_sigma_range: float = option(25.5, "JBU range sigma", unit="grey levels 0-255", source="ACMM", above=0)
    jbu_radius: int = option(2, "JBU window radius", unit="low-res px", source="ACMM", low=1, high=8)
    # --- ablation switches: the default is the paper's method, the alternative reproduces its ablations or ACMM
    pattern: str = option("deepc", "samples: 'deepc' 6 per direction at 3..13 px, 'deepc_far' 3..23, 'acmm' 8 regions",
                          source="paper", choices=PATTERNS)
    plane_propagation: bool = option(True, "propagate a neighbour's plane (on) or its raw depth (off)",
                                     source="paper")
    combos: str = option("acmm5", "combination hypotheses: ACMM's five or all eight of {cur,prt,rnd}²",
                         source="ACMM", choices=COMBOS)
    view_sampling: str = option("monte_carlo", "view weights: Monte-Carlo counts or deterministic weights",
                                source="ACMM", choices=VIEW_SAMPLING)
    ncc_weighting: str = option("colmap", "bilateral weights: 'colmap' squared Gaussian or 'acmm' non-squared",
                                source="paper", choices=WEIGHTINGS)
    acmm_sigma_color: float = option(3.0, "bilateral colour sigma, 'acmm' weighting", unit="grey levels 0-255",
                                     source="ACMM", above=0)
    # --- run
    seed: int = option(0, "random seed; the same seed gives the same maps whatever the thread count",
                       source="ours", low=0, below=2**63)
    num_threads: int = option(0, "numba threads (0 = all available)", source="ours", low=0)

    def validate(self) -> PatchMatchOptions:
        super().validate()
        check(self.window_step <= self.window // 2, "window_step", self.window_step, "must be in 1..window//2")
        check(self.fine_window_step <= max(1, self.fine_window // 2), "fine_window_step", self.fine_window_step,
              "must be in 1..fine_window//2")
        check(self.k_viewsel <= self.k_update, "k_update", self.k_update, "must be in k_viewsel..32")
        check(self.prior_out <= self.prior_in, "prior_in/prior_out", (self.prior_in, self.prior_out),
              "need 0 <= prior_out <= prior_in")
        return self

    def pass_iterations(self, pass_index: int) -> int:
        """Red-black iterations of pass ``pass_index`` (0 = photometric, >= 1 geometric)."""
        if self.iterations is not None:
            return int(self.iterations)
        if self.schedule == "acmm":
            return 3 if pass_index == 0 else 2
        return 8

    def window_offsets(self) -> list[int]:
        """1-D sample offsets of the matching window, e.g. [-5, -3, -1, 1, 3, 5]."""
        r = self.window // 2
        return list(range(-r, r + 1, self.window_step))

    def fine_window_offsets(self) -> list[int]:
        """1-D sample offsets of the fine window (empty when it is off), e.g. [-2, -1, 0, 1, 2]."""
        r = self.fine_window // 2
        return list(range(-r, r + 1, self.fine_window_step)) if self.fine_window else []


# The size rule of a view's candidate row cache (state.ViewState.prepare_caches), beside the options so that the
# memory estimate (engine/run/memory.py, deepc info) reads it without the kernels. The cache takes
# K_up · (4 N + 1) + 8 bytes per pixel (129 MB at 768x512 with 5 sources, 255 MB with 10); above this it is
# left out (results are the same either way, only slower).
ROW_CACHE_MAX_BYTES = 2 << 30


def row_cache_bytes(h: int, w: int, k_up: int, n_sources: int) -> int:
    """Bytes of the candidate row cache of an (h, w) view with ``k_up`` candidates and ``n_sources`` sources."""
    return h * w * (k_up * (4 * n_sources + 1) + 4 + 4)
