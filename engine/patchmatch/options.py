"""``PatchMatchOptions``: every PatchMatch setting with the SPEC.md §12 defaults (``ncc`` and ``pm``)."""

from __future__ import annotations

import dataclasses
import math

from engine.options import Options, check, option

SCHEDULES = ("paper", "acmm")
PATTERNS = ("deepc", "deepc_far", "acmm")
WEIGHTINGS = ("colmap", "acmm")
VIEW_SAMPLING = ("monte_carlo", "deterministic")
COMBOS = ("acmm5", "all8")
EPS_SCHEDULES = ("pass", "global")
RESTORER_REFERENCES = ("upsampled", "random")


@dataclasses.dataclass
class PatchMatchOptions(Options):
    """Multi-scale PatchMatch MVS (ACMM backbone with the DeepC modifications, SPEC.md §2)."""

    # --- schedule (§2.5, §2.11)
    schedule: str = option("paper", "red-black iterations per pass: 'paper' = 8 in every pass, "
                           "'acmm' = 3 photometric / 2 geometric", choices=SCHEDULES)
    iterations: int | None = option(None, "override: this many red-black iterations in every pass")
    levels: int = option(3, "pyramid levels (factor 0.5 between levels); fewer are used if the "
                         "coarsest level would be smaller than min_level_size")
    min_level_size: int = option(16, "smallest allowed shorter image side at the coarsest level (px)")
    geom_passes: int = option(2, "geometric-consistency passes per level after the photometric pass")
    # --- matching cost (§2.3)
    window: int = option(11, "matching window size (odd, pixels)")
    window_step: int = option(2, "sampling step inside the window (2 = ACMM's 36 samples)")
    fine_window: int = option(5, "small dense window (odd) used instead of `window` at pixels whose texture fills "
                              "it, within fine_edge_radius of depth edges; 0 = off, one window everywhere (SPEC). "
                              "Removes most of the 11 px window's foreground fattening along occlusion edges "
                              "(tiny: 80 -> 89 % within 1 %); with fine_edge_radius=0 it is used on every "
                              "textured pixel, less precise inside large weakly textured surfaces "
                              "(benchmarks/results/fine_window*.json)")
    fine_window_step: int = option(1, "sampling step inside the fine window")
    fine_sigma_spatial: float = option(1.5, "bilateral spatial sigma of the fine window (pixels)")
    fine_sigma_color: float = option(0.05, "bilateral colour sigma of the fine window ('colmap' weighting, "
                                     "intensities in [0,1]; 'acmm' weighting keeps acmm_sigma_color)")
    fine_min_var: float = option(1e-3, "a pixel uses the fine window when the intensity variance under the "
                                 "fine window's spatial weights and sigma_color reaches this (intensities "
                                 "in [0,1]; image noise of 1 grey level is 1.5e-5)")
    fine_max_level: int = option(0, "with fine_window: coarsest pyramid level that uses it (0 = the finest level "
                                 "only; coarser levels then match with the standard window alone)")
    fine_edge_radius: int = option(5, "with fine_window: use it only within this many pixels (Chebyshev) of a depth "
                                   "discontinuity of the map a pass starts from, never in the random-start pass; "
                                   "0 = wherever the texture test allows")
    fine_edge_jump: float = option(0.02, "a pair of neighbouring pixels is a depth discontinuity when each one's "
                                   "plane predicts the other's depth with a relative error above this")
    fine_crease_angle: float = option(
        20.0, "with fine_window: neighbouring pixels whose planes' normals differ by more than this (degrees) are "
        "an edge too (a crease: wall meets floor, box stands on ground), where the 11 px window also straddles two "
        "planes; 0 = depth discontinuities only (SPEC). With fine_crease_min_var_ratio 0.1: tiny 89.5 -> 90.1 % "
        "within 1 %, small +0.2 points and fused F1 at 1 cm +0.6, fountain_p11 at 192 px +0.8 and F1 at 2 cm +0.8; "
        "the held-out synthetic scenes -0.2 and -0.4 F1 at 1 cm (their seed spread), nothing at 2 cm "
        "(benchmarks/results/fine_crease_angle.json)")
    fine_crease_min_var_ratio: float = option(
        0.1, "with fine_crease_angle: in the band of a crease (not of a depth discontinuity) a pixel also needs the "
        "variance under the fine window's own weights (its sharp fine_sigma_color) to reach this fraction of the "
        "standard window's; 0 = no such test. On piecewise-constant texture (checkers, print) the sharp colour "
        "weight keeps little but the centre's colour, so the small window is nearly flat while the large one "
        "sees the pattern; without the test, noisy normals in such scenes make 'creases' everywhere and cost "
        "synth_01000 8 points of F1 at 1 cm")
    ncc_weighting: str = option("colmap", "bilateral weights: 'colmap' (squared Gaussian, sigma_color on "
                                "[0,1]) or 'acmm' (non-squared, acmm_sigma_color on 0-255)", choices=WEIGHTINGS)
    sigma_spatial: float = option(5.0, "bilateral spatial sigma (pixels)")
    sigma_color: float = option(0.2, "bilateral colour sigma for 'colmap' weighting (intensities in [0,1])")
    acmm_sigma_color: float = option(3.0, "bilateral colour sigma for 'acmm' weighting (0-255 grey levels)")
    min_var: float = option(1e-5, "weighted variance below which a window is textureless (cost 2)")
    init_top_k: int = option(4, "initial cost = mean of the k best per-view costs (§2.4)")
    # --- sampling, propagation, refinement (§2.6, §2.7, §2.10)
    pattern: str = option("deepc", "sampling pattern: 'deepc' (6 per direction at 3..13), 'deepc_far' "
                          "(3..23), 'acmm' (8 adaptive regions, bugs fixed)", choices=PATTERNS)
    plane_propagation: bool = option(True, "propagate a neighbour's plane (True) or its raw depth (False)")
    k_viewsel: int = option(8, "best samples whose costs drive view selection")
    k_update: int = option(16, "best samples evaluated as update candidates (>= k_viewsel)")
    combos: str = option("acmm5", "combination hypotheses: ACMM's five or all eight {cur,prt,rnd}^2",
                         choices=COMBOS)
    eps_schedule: str = option("global", "perturbation scale eps = 2^-t: 'pass' = t is the iteration index, "
                               "reset at the start of every pass (SPEC §2.5 [rec]); 'global' = t counts the "
                               "iterations of all earlier passes and levels too, floored at eps_min (short "
                               "ACMM-schedule passes and finer levels otherwise never perturb finely)",
                               choices=EPS_SCHEDULES)
    eps_min: float = option(2.0**-7, "smallest perturbation scale with eps_schedule='global' (2^-7 = the "
                            "paper's last iteration)")
    normal_perturb_retries: int = option(3, "retries with halved angle when a perturbed normal faces away")
    min_improvement: float = option(
        0.003, "a pixel's hypothesis is replaced only by one whose aggregated cost is lower by more than this "
        "(cost units, [0, 2]), except in the last iteration of each pass, where any lower cost wins; 0 = any lower "
        "cost throughout (ACMM, SPEC). Near convergence 80 % of the pixels still swap their plane in every "
        "iteration for a slightly cheaper one (fountain_p11 768), and each swap voids the cached costs of the "
        "pixel and of the neighbours that sample it. 0.003 against 0: ACMM schedule 299 -> 249-267 s the same "
        "day (OpenMVS: 285 s), paper schedule 896 -> 570-665 s (2.0-2.3x OpenMVS), within 1 % and fused F1 within the "
        "seed-to-seed spread (seeds 0-2 on tiny, small and two held-out scenes; tiny with the paper schedule "
        "89.3 -> 89.5 % within 1 %); the same margin in every iteration lost 0.7-4.5 points of F1 at 1 cm "
        "(benchmarks/results/min_improvement.json)")
    # --- view selection (§2.8)
    view_sampling: str = option("monte_carlo", "view weights: Monte-Carlo counts or deterministic weights",
                                choices=VIEW_SAMPLING)
    mc_samples: int = option(15, "Monte-Carlo draws for the view weights")
    tau0: float = option(0.8, "good-cost threshold at iteration 0: tau_g(t) = tau0 * exp(-t^2 / alpha)")
    alpha: float = option(0.0, "decay of the good-cost threshold over the iterations t of a pass; 0 = none, "
                          "tau_g = tau0 throughout (SPEC: 90, made for ACMM's 3 iterations per pass: with the "
                          "paper's 8 it falls to 0.46 tau0, and within 1 % peaks after 2-4 iterations of a pass and "
                          "then declines; constant: +0.05..+0.9 points within 1 % and +0.4..+1.2 F1 at 2 cm on "
                          "five held-out scenes, tiny 89.0 -> 89.5, benchmarks/results/tau_g_decay.json)")
    tau_bad: float = option(1.2, "bad-cost threshold")
    beta: float = option(0.3, "width of the Gaussian turning good costs into view weights")
    beta_fallback: float = option(0.4, "width used for views with few good costs")
    n_good_gt: int = option(2, "a view needs more than this many good costs for the full weight")
    n_bad_lt: int = option(3, "a view with this many bad costs gets weight 0")
    prior_in: float = option(0.9, "neighbourhood prior for a view selected by a 4-neighbour")
    prior_out: float = option(0.1, "neighbourhood prior for a view not selected by a 4-neighbour")
    # --- geometric consistency (§2.9)
    geom_lambda: float = option(0.2, "weight of the geometric term in geometric passes")
    geom_max: float = option(3.0, "truncation of the forward-backward reprojection error (px)")
    # --- multi-scale (§2.11)
    detail_restorer: bool = option(True, "keep the upsampled hypothesis unless the new cost is much lower")
    detail_restorer_delta: float = option(0.1, "detail restorer: required cost improvement")
    detail_restorer_reference: str = option(
        "random", "detail restorer reference cost Cpre: 'upsampled' = top-k photometric cost of the upsampled "
        "hypothesis (SPEC §2.7 step 7 / §11.15; blocks almost all fine-level refinement, since refining an "
        "already good plane rarely gains 0.1); 'random' = top-k cost of the upsampled depth with a random "
        "normal, i.e. how well an arbitrary plane matches there (what ACMM's code effectively compares with, "
        "its Cpre plane has an uninitialised normal): textured pixels refine freely, weakly textured ones "
        "keep the upsampled hypothesis unless the new one is clearly better", choices=RESTORER_REFERENCES)
    jbu_sigma_spatial: float = option(0.5, "JBU spatial sigma (low-res pixels)")
    jbu_sigma_range: float = option(25.5, "JBU range sigma (0-255 grey levels)")
    jbu_radius: int = option(2, "JBU window radius (low-res pixels)")
    # --- run
    seed: int = option(0, "random seed; same seed gives the same maps whatever the thread count")
    num_threads: int = option(0, "numba threads (0 = all available)")

    def validate(self) -> PatchMatchOptions:
        super().validate()
        check(self.iterations is None or (isinstance(self.iterations, int) and self.iterations >= 1),
              "iterations", self.iterations, "must be None or an integer >= 1")
        check(1 <= self.levels <= 8, "levels", self.levels, "must be in 1..8")
        check(self.min_level_size >= 8, "min_level_size", self.min_level_size, "must be >= 8")
        check(0 <= self.geom_passes <= 4, "geom_passes", self.geom_passes, "must be in 0..4")
        check(self.window >= 3 and self.window % 2 == 1, "window", self.window, "must be odd and >= 3")
        check(1 <= self.window_step <= self.window // 2, "window_step", self.window_step,
              "must be in 1..window//2")
        check(self.fine_window == 0 or (self.fine_window >= 3 and self.fine_window % 2 == 1), "fine_window",
              self.fine_window, "must be 0 (off) or odd and >= 3")
        check(1 <= self.fine_window_step <= max(1, self.fine_window // 2), "fine_window_step",
              self.fine_window_step, "must be in 1..fine_window//2")
        check(self.fine_min_var >= 0, "fine_min_var", self.fine_min_var, "must be >= 0")
        check(0 <= self.fine_crease_min_var_ratio <= 1, "fine_crease_min_var_ratio", self.fine_crease_min_var_ratio,
              "must be in [0, 1]")
        check(0 <= self.fine_max_level <= 7, "fine_max_level", self.fine_max_level, "must be in 0..7")
        check(0 <= self.fine_edge_radius <= 32, "fine_edge_radius", self.fine_edge_radius, "must be in 0..32")
        check(self.fine_edge_jump > 0, "fine_edge_jump", self.fine_edge_jump, "must be > 0")
        check(0 <= self.fine_crease_angle < 90, "fine_crease_angle", self.fine_crease_angle, "must be in [0, 90)")
        for name in ("sigma_spatial", "sigma_color", "acmm_sigma_color", "fine_sigma_spatial", "fine_sigma_color",
                     "beta", "beta_fallback", "jbu_sigma_spatial", "jbu_sigma_range"):
            check(getattr(self, name) > 0, name, getattr(self, name), "must be > 0")
        check(self.alpha >= 0, "alpha", self.alpha, "must be >= 0 (0 = constant good-cost threshold)")
        check(self.min_var >= 0, "min_var", self.min_var, "must be >= 0")
        check(1 <= self.init_top_k <= 32, "init_top_k", self.init_top_k, "must be in 1..32")
        check(1 <= self.k_viewsel <= 32, "k_viewsel", self.k_viewsel, "must be in 1..32")
        check(self.k_viewsel <= self.k_update <= 32, "k_update", self.k_update, "must be in k_viewsel..32")
        check(0 <= self.normal_perturb_retries <= 10, "normal_perturb_retries", self.normal_perturb_retries,
              "must be in 0..10")
        check(1 <= self.mc_samples <= 1000, "mc_samples", self.mc_samples, "must be in 1..1000")
        check(0 < self.tau0 <= 2, "tau0", self.tau0, "must be in (0, 2]")
        check(0 < self.tau_bad <= 2, "tau_bad", self.tau_bad, "must be in (0, 2]")
        check(self.n_good_gt >= 0 and self.n_bad_lt >= 1, "n_good_gt/n_bad_lt",
              (self.n_good_gt, self.n_bad_lt), "must be >= 0 and >= 1")
        check(0 <= self.prior_out <= self.prior_in, "prior_in/prior_out", (self.prior_in, self.prior_out),
              "need 0 <= prior_out <= prior_in")
        check(self.geom_lambda >= 0, "geom_lambda", self.geom_lambda, "must be >= 0")
        check(self.geom_max > 0, "geom_max", self.geom_max, "must be > 0")
        check(0 < self.eps_min <= 1, "eps_min", self.eps_min, "must be in (0, 1]")
        check(0 <= self.min_improvement < math.inf, "min_improvement", self.min_improvement,
              "must be >= 0 and finite")
        check(self.detail_restorer_delta >= 0, "detail_restorer_delta", self.detail_restorer_delta, "must be >= 0")
        check(1 <= self.jbu_radius <= 8, "jbu_radius", self.jbu_radius, "must be in 1..8")
        check(0 <= self.seed < 2**63, "seed", self.seed, "must be in 0..2^63-1")
        check(self.num_threads >= 0, "num_threads", self.num_threads, "must be >= 0 (0 = all)")
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
