"""The per-view maps of a finished run, read from its folder (``engine/run/folder.py``), and the maps each
pipeline filters and fuses.

The viewer's session and the regression report both read runs through here.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from engine.core.errors import DeepCError
from engine.refinement.guard import keep_confident, kept_estimates
from engine.refinement.options import RefinementOptions
from engine.run.folder import read_map
from engine.scene import Scene


@dataclasses.dataclass
class ViewData:
    """The maps of one view read from an output folder (None where the run did not write them)."""

    depth: np.ndarray
    normal: np.ndarray
    counter: np.ndarray | None
    confidence: np.ndarray | None
    refined_depth: np.ndarray | None
    refined_normal: np.ndarray | None
    refined_counter: np.ndarray | None = None  # counter maps of the refined maps (older full runs: None)
    refined_confidence: np.ndarray | None = None  # confidence of the refined maps (second network)
    cost: np.ndarray | None = None  # PatchMatch's matching cost (1 - NCC, 0..2)

    def maps(self, pipeline: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(depth, normal, confidence, counter) that ``pipeline`` filters and fuses: ``full`` takes the refined
        maps with their own confidence and counter maps (the first network's for older full runs), except where
        network 1 trusts the PatchMatch estimate (``refinement.keep_confident``, as the pipeline fuses them)."""
        if pipeline != "full":
            return self.depth, self.normal, self.confidence, self.counter
        counter = self.counter if self.refined_counter is None else self.refined_counter
        if self.refined_confidence is None or self.confidence is None:
            return self.refined_depth, self.refined_normal, self.confidence, counter
        threshold = RefinementOptions().keep_confident
        depth, normal, confidence = keep_confident(self.depth, self.normal, self.confidence, self.refined_depth,
                                                   self.refined_normal, self.refined_confidence, threshold)
        if self.counter is not None and counter is not None:
            counter = np.where(kept_estimates(self.depth, self.confidence, threshold), self.counter, counter)
        return depth, normal, confidence, counter


def read_view_data(out_dir: str | Path, scene: Scene) -> list[ViewData]:
    """The maps of every view of ``scene`` in the run folder ``out_dir``; a view without depth or normal
    map is a :class:`DeepCError`."""
    data = []
    for v in scene.views:
        depth = read_map(out_dir, "depth", v.name)
        normal = read_map(out_dir, "normal", v.name)
        if depth is None or normal is None:
            raise DeepCError(f"the run has no depth/normal map for view {v.name}", out_dir)
        data.append(ViewData(depth, normal, read_map(out_dir, "counter", v.name),
                             read_map(out_dir, "confidence", v.name), read_map(out_dir, "refined_depth", v.name),
                             read_map(out_dir, "refined_normal", v.name), read_map(out_dir, "refined_counter", v.name),
                             read_map(out_dir, "refined_confidence", v.name), read_map(out_dir, "cost", v.name)))
    return data
