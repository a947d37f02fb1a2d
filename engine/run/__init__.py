"""A run of stages: the pipeline that strings the stages together (``pipeline``), the per-view bodies it and the
executors share (``per_view``), what a pipeline fuses (``fused_maps``), the run folder (``folder``), PatchMatch
checkpoints and pass history, probing and refining a finished run, the memory estimate, and the executors
(``distributed/``). Stage packages never import this package."""
