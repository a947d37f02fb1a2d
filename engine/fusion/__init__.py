"""COLMAP-style fusion of depth maps into one point cloud (Schönberger et al., ECCV 2016).

``options`` holds the thresholds and presets, ``cloud`` the input and output records, ``packing`` and
``kernel`` the numba implementation, ``cached`` the same fusion reading views on demand through a bounded cache
(COLMAP's workspace cache), ``stream`` the cloud written into its PLY as fusion makes it (the cloud then lives on
disk, a ``DiskCloud``), ``ply`` the cloud's file format and ``views`` the scene adapter.
"""

from engine.fusion.cloud import DiskCloud, FusedCloud, FusionView
from engine.fusion.kernel import fuse
from engine.fusion.options import DEFAULT_PRESET, FUSION_PRESETS, FusionOptions
from engine.fusion.ply import read_fused_ply, write_fused_ply
from engine.fusion.views import views_from_scene

__all__ = ["DEFAULT_PRESET", "FUSION_PRESETS", "DiskCloud", "FusedCloud", "FusionOptions", "FusionView", "fuse",
           "read_fused_ply", "views_from_scene", "write_fused_ply"]
