"""Confidence-guided piece-wise planar depth refinement (Rossi et al., CVPR 2020).

As DeepC-MVS uses it (Kuhn et al. 2020, §4.2): the confidence of the PatchMatch maps weighs the data term.
"""

from engine.refinement.energy import ScaleProblem, energy, energy_terms
from engine.refinement.graph import SimilarityGraph, similarity_graph
from engine.refinement.options import RefinementOptions
from engine.refinement.planes import normal_to_u, u_to_normal
from engine.refinement.refine import NoDataError, RefinedMap, build_problem, map_energy, refine_depth

__all__ = ["NoDataError", "RefinedMap", "RefinementOptions", "ScaleProblem", "SimilarityGraph", "build_problem",
           "energy", "energy_terms", "map_energy", "normal_to_u", "refine_depth", "similarity_graph",
           "u_to_normal"]
