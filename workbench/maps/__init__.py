"""A run's per-view maps as the viewer, the rerun stream and the report read them (``run_maps``), drawn as images
(``images``), and GT depth at a PatchMatch level's resolution (``gt_depth``)."""
