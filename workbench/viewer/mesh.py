"""The viewer's mesh folder: the run's ``mesh.ply`` beside or instead of the cloud, and a new mesh of the tuned
cloud on request, made in a worker thread as ``deepc mesh`` makes it (Poisson on the cloud, or TSDF of the maps
the current filters keep)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from engine.meshing.mesh import TriangleMesh, read_mesh
from engine.meshing.options import MeshOptions
from engine.meshing.stage import mesh_run
from workbench.viewer.scheduler import NewestWorker

SHOW = ("cloud", "mesh", "cloud + mesh")
MESH_COLOR = (190, 190, 200)  # viser's simple meshes take one colour: a light grey shades the surface best


class MeshPanel:
    """GUI and worker of the mesh folder; ``app`` is the :class:`workbench.viewer.app.ViewerApp` it belongs to."""

    def __init__(self, app: Any):
        self.app = app
        gui = app.server.gui
        self.handle = None
        self.mesh: TriangleMesh | None = None
        with gui.add_folder("Mesh", expand_by_default=False):
            self.show = gui.add_dropdown("Show", options=SHOW, initial_value="cloud", disabled=True,
                                         hint="no mesh yet: make one below, or run deepc mesh on the run")
            self.method = gui.add_dropdown("Method", options=("poisson", "tsdf"), initial_value="poisson",
                                           hint="poisson: the current cloud; tsdf: the maps the current filters keep")
            self.button = gui.add_button("Mesh the current cloud", disabled=not app.session.has_maps)
            self.status = gui.add_markdown("no mesh yet" if app.session.has_maps else "no maps to mesh")
        self.worker: NewestWorker[str] = NewestWorker(self._compute, self._error, name="deepc-mesh")
        self.show.on_update(lambda _event: self.apply_visibility())
        self.button.on_click(lambda _event: self.request(str(self.method.value)))
        out_dir = app.session.out_dir
        if out_dir is not None and (out_dir / "mesh.ply").is_file():
            self._show_mesh(read_mesh(out_dir / "mesh.ply"), "the run's mesh.ply", switch_to=None)

    def request(self, method: str) -> None:
        """Mesh the cloud shown now (its exact result) with ``method`` in the worker; a newer request wins."""
        self.status.content = f"meshing ({method})…"
        self.worker.submit(method)

    def _compute(self, method: str) -> None:
        app = self.app
        app.wait_idle(timeout=120)
        if app.cloud is None or app.cloud_params is None:
            self.status.content = "no cloud to mesh yet"
            return
        start = time.perf_counter()
        depths = [depth for depth, _ in app.session.filtered_maps(app.cloud_params)]
        mesh, info = mesh_run(app.session.scene, app.cloud, depths, MeshOptions(method=method))
        notes = "".join(f"  \n{note}" for note in info["notes"])
        self._show_mesh(mesh, f"{method} of the current cloud, {time.perf_counter() - start:.1f} s{notes}",
                        switch_to="cloud + mesh")

    def _error(self, exc: Exception) -> None:
        self.status.content = f"**mesh failed:** {exc}"

    def _show_mesh(self, mesh: TriangleMesh, label: str, switch_to: str | None) -> None:
        with self.app.server.atomic():
            self.handle = self.app.server.scene.add_mesh_simple(
                "/mesh", np.asarray(mesh.vertices, np.float32), np.asarray(mesh.triangles, np.uint32),
                color=MESH_COLOR, side="double", visible=False)
            self.status.content = f"**mesh:** {len(mesh):,} triangles · {label}"
            self.show.disabled = False
            self.show.hint = "what the 3D view draws"
            if switch_to is not None:
                self.show.value = switch_to
        self.apply_visibility()
        self.mesh = mesh  # last: a reader that sees the mesh sees its handle, status and Show choice too

    def apply_visibility(self) -> None:
        """Draw the cloud, the mesh or both, as the Show dropdown says."""
        show = str(self.show.value)
        if self.handle is not None:
            self.handle.visible = show in ("mesh", "cloud + mesh")
        if self.app.cloud_handle is not None:
            self.app.cloud_handle.visible = show in ("cloud", "cloud + mesh") or self.handle is None

    def stop(self) -> None:
        self.worker.stop(timeout=10)
