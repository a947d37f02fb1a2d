"""Meshing settings (``MeshOptions``): which method, and the knobs of screened Poisson and of TSDF integration."""

from __future__ import annotations

import dataclasses

from engine.core.options import Options, option

MESH_METHODS = ("none", "poisson", "tsdf")


@dataclasses.dataclass
class MeshOptions(Options):
    """How ``deepc run --mesh`` and ``deepc mesh`` turn a run into a surface (docs/decisions.md, "Meshing")."""

    method: str = option("none", "'poisson': the fused cloud; 'tsdf': the maps fusion used; 'none': no mesh",
                         source="ours", choices=MESH_METHODS)
    # --- screened Poisson (Kazhdan & Hoppe 2013) on the fused, oriented cloud
    poisson_depth: int = option(0, "octree depth of the Poisson solve; 0 = auto, cells about one point spacing",
                                source="ours", off=0, low=5, high=12)
    poisson_outlier_pct: float = option(0.5, "solve within the box of the 0.5-99.5 percentiles of every axis",
                                        unit="%", source="ours", low=0, below=10)
    poisson_trim_quantile: float = option(0.05, "drop vertices whose Poisson density is below this quantile",
                                          source="ours", low=0, below=1)
    # --- TSDF integration (Curless & Levoy 1996) of the depth maps
    tsdf_voxel_px: float = option(1.5, "voxel edge in pixel footprints at the views' median depth", unit="px",
                                  source="ours", above=0)
    tsdf_trunc_voxels: float = option(4.0, "truncation distance of the signed distance", unit="voxels",
                                      source="ours", above=1)
    tsdf_min_views: float = option(2.0, "keep the surface where at least this many views agree (as fusion's 2 pixels)",
                                   source="ours", low=1)
    max_memory_gb: float = option(4.0, "refuse a TSDF volume estimated to need more than this", unit="GB",
                                  source="ours", above=0)
    threads: int = option(0, "open3d threads for Poisson (0 = all cores)", source="ours", low=0)
