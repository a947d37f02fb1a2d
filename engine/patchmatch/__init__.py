"""PatchMatch MVS engine (numba, CPU): SPEC.md §2 with the DeepC modifications.

Public API::

    from engine.patchmatch import PatchMatchOptions, PatchMatchView, ViewMaps, run_patchmatch
    maps = run_patchmatch(views, PatchMatchOptions(schedule="acmm"), observer=obs)

Modules: ``options`` (settings), ``rng`` (counter-based randomness), ``geometry`` (homographies,
plane propagation, normals), ``ncc`` (bilateral NCC), ``propagation`` (sampling patterns),
``view_selection`` (ACMM multi-hypothesis view weights), ``kernels`` (numba half-step and init
kernels), ``pyramid`` (area downsampling, JBU), ``context`` (per-view precomputation), ``engine``
(the multi-scale driver) and ``reference`` (slow plain-Python references for the tests).
"""

from engine.patchmatch.engine import PatchMatchView, ViewMaps, effective_levels, run_patchmatch
from engine.patchmatch.options import PatchMatchOptions

__all__ = ["PatchMatchOptions", "PatchMatchView", "ViewMaps", "effective_levels", "run_patchmatch"]
