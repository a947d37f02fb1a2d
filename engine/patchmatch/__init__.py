"""PatchMatch MVS engine (numba, CPU): Xu & Tao 2019 ACMM's multi-scale PatchMatch with the modifications of
Kuhn et al. 2020 DeepC-MVS, on Schönberger et al. 2016 COLMAP's bilateral NCC and perturbations.

Public API::

    from engine.patchmatch import PatchMatchOptions, PatchMatchView, ViewMaps, run_patchmatch
    maps = run_patchmatch(views, PatchMatchOptions(schedule="acmm"), observer=obs)

One view at one level (tests, benchmarks)::

    state = ViewState.zeros(h, w)            # or maps to start from
    ctx = build_context(ref_img, ref_cam, src_imgs, src_cams, options)
    counts = run_view_level(state, ctx, options, zmin, zmax)

Modules: ``options`` (settings), ``rng`` (counter-based randomness), ``geometry`` (homographies,
plane propagation, normals), ``ncc`` (bilateral NCC), ``propagation`` (sampling patterns),
``view_selection`` (ACMM multi-hypothesis view weights), ``records`` (the named records the kernels take),
``kernels`` (numba half-step and init kernels), ``state`` (a view's maps and cost caches), ``view_pass``
(one view at one level), ``pyramid`` (area downsampling, JBU), ``context`` (per-view precomputation),
``multiscale`` (the multi-scale driver) and ``probe/`` (the pixel probe and why each candidate won or lost).
Plain-numpy references of the kernels live in ``support/patchmatch_reference.py``.
"""

from engine.core.lazy import lazy_attributes

# Loaded on first use (engine/core/lazy.py): the command line imports the options alone, without numba and scipy.
_WHERE = {"ViewContext": "context", "build_context": "context", "PatchMatchView": "multiscale",
          "ViewMaps": "multiscale", "effective_levels": "multiscale", "run_patchmatch": "multiscale",
          "PatchMatchOptions": "options", "KernelParams": "records", "kernel_params": "records",
          "ViewState": "state", "run_view_level": "view_pass"}
__all__ = sorted(_WHERE)
__getattr__ = lazy_attributes(__name__, _WHERE, globals())
