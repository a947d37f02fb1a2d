"""COLMAP-style fusion of depth maps into one point cloud (Schönberger et al., ECCV 2016).

``options`` holds the thresholds and presets, ``cloud`` the input and output records, ``packing`` and
``kernel`` the numba implementation, ``cached`` the same fusion reading views on demand through a bounded cache
(COLMAP's workspace cache), ``stream`` the cloud written into its PLY as fusion makes it (the cloud then lives on
disk, a ``DiskCloud``), ``ply`` the cloud's file format and ``views`` the scene adapter.
"""

from engine.core.lazy import lazy_attributes

# Loaded on first use (engine/core/lazy.py): the command line imports the options alone, without numba.
_WHERE = {"DiskCloud": "cloud", "FusedCloud": "cloud", "FusionView": "cloud", "fuse": "kernel",
          "DEFAULT_PRESET": "options", "FUSION_PRESETS": "options", "FusionOptions": "options",
          "read_fused_ply": "ply", "write_fused_ply": "ply", "views_from_scene": "views"}
__all__ = sorted(_WHERE)
__getattr__ = lazy_attributes(__name__, _WHERE, globals())
