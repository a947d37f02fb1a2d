"""A run's per-view maps (read by ``engine.run.fused_maps``) drawn as images (``images``), and GT depth at a
PatchMatch level's resolution (``gt_depth``)."""
