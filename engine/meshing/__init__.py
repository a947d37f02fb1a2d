"""Surfaces from a run: screened Poisson on the fused cloud or TSDF integration of the depth maps (open3d).

``options`` holds ``MeshOptions``, ``mesh`` the triangle-mesh record and its PLY file, ``poisson`` and ``tsdf``
the two methods, ``decimate`` a mesh within a triangle budget, ``stage`` the stage of a run, ``sampling`` the
uniform surface samples that let a mesh be scored like a cloud. open3d is imported only inside the functions that
need it (it takes seconds to load).
"""

from engine.core.lazy import lazy_attributes

# Loaded on first use (engine/core/lazy.py): the command line imports the options alone, without numba and scipy.
_WHERE = {"decimate": "decimate", "TriangleMesh": "mesh", "read_mesh": "mesh", "write_mesh_ply": "mesh",
          "MESH_METHODS": "options",
          "MeshOptions": "options", "poisson_mesh": "poisson", "point_spacing": "sampling",
          "sample_surface": "sampling", "evaluate_mesh": "stage", "mesh_run": "stage", "tsdf_mesh": "tsdf",
          "tsdf_voxel_size": "tsdf"}
__all__ = sorted(_WHERE)
__getattr__ = lazy_attributes(__name__, _WHERE, globals())
