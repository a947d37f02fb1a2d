"""Surfaces from a run: screened Poisson on the fused cloud or TSDF integration of the depth maps (open3d).

``options`` holds ``MeshOptions``, ``mesh`` the triangle-mesh record and its PLY file, ``poisson`` and ``tsdf``
the two methods, ``decimate`` a mesh within a triangle budget, ``stage`` the stage of a run, ``sampling`` the
uniform surface samples that let a mesh be scored like a cloud. open3d is imported only inside the functions that
need it (it takes seconds to load).
"""

from engine.meshing.decimate import decimate
from engine.meshing.mesh import TriangleMesh, read_mesh, write_mesh_ply
from engine.meshing.options import MESH_METHODS, MeshOptions
from engine.meshing.poisson import poisson_mesh
from engine.meshing.sampling import point_spacing, sample_surface
from engine.meshing.stage import evaluate_mesh, mesh_run
from engine.meshing.tsdf import tsdf_mesh, tsdf_voxel_size

__all__ = ["MESH_METHODS", "MeshOptions", "TriangleMesh", "decimate", "evaluate_mesh", "mesh_run", "point_spacing",
           "poisson_mesh", "read_mesh", "sample_surface", "tsdf_mesh", "tsdf_voxel_size", "write_mesh_ply"]
