"""The viewer's mesh folder: the run's ``mesh.ply`` beside or instead of the cloud, and a new mesh of the tuned
cloud on request, made in a worker thread as ``deepc mesh`` makes it (Poisson on the cloud, or TSDF of the maps
the current filters keep).

A mesh goes to the browser only once the Show dropdown asks for it, decimated to the triangle budget
(``engine/meshing/decimate.py``; sample small's Poisson mesh, 1.19 M triangles and 31.6 MB, took about 60 s to
show in software WebGL), its vertices coloured by their distance to the nearest GT point on the cloud's GT scale
(cm) when the scene has GT points, else by the images' colours. The mesh's own scores, as ``deepc mesh`` takes
them (``engine.meshing.evaluate_mesh`` on the whole mesh), go to the Metrics folder.
"""

from __future__ import annotations

import dataclasses
import io
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from engine.evaluation import EvaluationOptions
from engine.meshing import MeshOptions, TriangleMesh, decimate, evaluate_mesh, mesh_run, read_mesh
from workbench.viewer.legends import note_html, scale_html
from workbench.viewer.scheduler import NewestWorker
from workbench.viewer.session import GT_DISTANCE

SHOW = ("cloud", "mesh", "cloud + mesh")
# Triangles sent to the browser at most: about 5 MB of GLB (uint32 faces; float32 positions and normals and RGBA
# colours of about half as many vertices), a sixth of sample small's Poisson mesh (docs/decisions.md, "Viewer: at
# most 200 000 points and 200 000 triangles ...").
TRIANGLE_BUDGET = 200_000
MIN_TRIANGLE_BUDGET = 1_000  # the control's minimum
SCORED_TOLERANCES = (0.02, 0.05)  # the mesh scores the Metrics folder shows (as deepc mesh prints them)


def mesh_scores_text(evaluation: dict[str, list[float]] | None) -> str:
    """The mesh's F1 (and accuracy / completeness) at 2 and 5 cm from an ``EvaluationResult.to_dict()``, as
    ``deepc mesh`` prints them; "" without scores."""
    if not evaluation:
        return ""
    parts = [f"F1 {f:.1f} at {100 * t:g} cm (accuracy {a:.1f} · completeness {c:.1f})"
             for t, a, c, f in zip(evaluation["tolerances"], evaluation["accuracy"], evaluation["completeness"],
                                   evaluation["f1"], strict=True)
             if any(abs(t - s) < 1e-9 for s in SCORED_TOLERANCES)]
    return "**mesh:** " + " · ".join(parts) + "  \n*the whole mesh's surface sampled and scored as deepc mesh does*"


@dataclasses.dataclass(frozen=True)
class SentMesh:
    """What the browser got: ``shown`` (``source`` decimated to ``budget``) under ``handle``."""

    source: TriangleMesh
    budget: int
    shown: TriangleMesh
    handle: Any


class MeshPanel:
    """GUI and workers of the mesh folder; ``app`` is the :class:`workbench.viewer.app.ViewerApp` it belongs to.

    Two workers: one makes meshes (seconds to minutes), one decimates, colours and sends the mesh when the Show
    dropdown asks for it; a send of a mesh in the making waits for it under ``_send_lock``."""

    def __init__(self, app: Any):
        self.app = app
        gui = app.server.gui
        self.mesh: TriangleMesh | None = None  # the whole mesh (the run's is read only when first shown)
        self.sent: SentMesh | None = None
        self.label = ""
        self._run_mesh: Path | None = None  # the run's mesh.ply, not read yet
        self._send_lock = threading.Lock()
        # no image-based lighting: viser's default environment map made a mesh's first frame seconds slower in
        # chromium's software WebGL (its lit-material shader and prefiltered map; one-off probes, docs/decisions.md);
        # the default lights still shade it, and points and frustums are unlit either way
        app.server.scene.configure_environment_map(hdri=None)
        with gui.add_folder("Mesh", expand_by_default=False):
            self.show = gui.add_dropdown("Show", options=SHOW, initial_value="cloud", disabled=True,
                                         hint="no mesh yet: make one below, or run deepc mesh on the run")
            self.triangle_budget = gui.add_number("Triangle budget (triangles)", initial_value=TRIANGLE_BUDGET,
                                                  min=MIN_TRIANGLE_BUDGET, max=10_000_000, step=1_000,
                                                  hint="most triangles sent to the browser (vertex clustering); "
                                                       "default from docs/decisions.md (software WebGL)")
            self.method = gui.add_dropdown("Method", options=("poisson", "tsdf"), initial_value="poisson",
                                           hint="poisson: the current cloud; tsdf: the maps the current filters keep")
            self.button = gui.add_button("Mesh the current cloud", disabled=not app.session.has_maps)
            self.status = gui.add_markdown("no mesh yet" if app.session.has_maps else "no maps to mesh")
            self.legend = gui.add_html("")
        self.worker: NewestWorker[str] = NewestWorker(self._compute, self._error, name="deepc-mesh")
        self.sender: NewestWorker[None] = NewestWorker(lambda _item: self._send(), self._error, name="deepc-mesh-send")
        self.show.on_update(lambda _event: self.apply_visibility())
        self.triangle_budget.on_update(lambda _event: self.apply_visibility())
        self.button.on_click(lambda _event: self.request(str(self.method.value)))
        out_dir = app.session.out_dir
        if out_dir is not None and (out_dir / "mesh.ply").is_file():
            # not read or sent yet: a whole Poisson mesh is tens of MB, and most sessions never show it
            self._run_mesh = out_dir / "mesh.ply"
            run = app.session.run
            block = (run.mesh if run is not None else None) or {}
            size = f"{block['triangles']:,} triangles · " if block.get("triangles") else ""
            self.label = "the run's mesh.ply"
            self.status.content = f"**mesh:** {size}{self.label} · sent when shown"
            self.app.mesh_metrics.content = mesh_scores_text(block.get("eval"))
            self.show.disabled = False
            self.show.hint = "what the 3D view draws (the mesh is sent when first shown)"

    def preload(self) -> None:
        """With a run's mesh to show, import what reading and decimating it needs in the background once the
        viewer is idle (call after the first cloud is requested): open3d takes ~1.7 s to import, which Show
        would otherwise wait for."""
        if self._run_mesh is None:
            return

        def load() -> None:
            self.app.wait_idle(timeout=120)
            import open3d  # noqa: F401  # lazy: open3d (most sessions never show the mesh)

        threading.Thread(target=load, name="deepc-mesh-import", daemon=True).start()

    @property
    def handle(self) -> Any:
        """The scene handle of the mesh sent, None before one is."""
        sent = self.sent
        return None if sent is None else sent.handle

    def budget(self) -> int:
        """The triangle budget control's value (at least its minimum, as the point budget's)."""
        return max(MIN_TRIANGLE_BUDGET, int(self.triangle_budget.value))

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
        with self._send_lock:
            self._run_mesh = None
            self.label = f"{method} of the current cloud, {time.perf_counter() - start:.1f} s{notes}"
            self.app.mesh_metrics.content = ""
            self.show.disabled = False
            self.show.hint = "what the 3D view draws"
            self.show.value = "cloud + mesh"  # (its callback queues a send of the old mesh: it finds this one)
            self._send_now(mesh)
            self.mesh = mesh
            self.apply_visibility()
        self._score(mesh)

    def _error(self, exc: Exception) -> None:
        self.status.content = f"**mesh failed:** {' '.join(str(exc).split())}"

    def _wanted(self) -> bool:
        return str(self.show.value) in ("mesh", "cloud + mesh")

    def _needs_send(self) -> bool:
        sent = self.sent
        if self.mesh is None and self._run_mesh is None:
            return False
        return sent is None or sent.source is not self.mesh or sent.budget != self.budget()

    def _send(self) -> None:
        """The sender's job: the current mesh (the run's read first) to the browser, if it is still wanted."""
        with self._send_lock:
            if not self._wanted() or not self._needs_send():
                return
            if self.mesh is None:
                self.status.content = f"**mesh:** reading {self.label}…"
                self.mesh = read_mesh(self._run_mesh)
                self._run_mesh = None
            mesh = self.mesh
            self._send_now(mesh)
        self.apply_visibility()
        if not self.app.mesh_metrics.content:
            self._score(mesh)

    def _send_now(self, mesh: TriangleMesh) -> None:
        """Decimate ``mesh`` to the budget, colour it and put it in the scene (hidden: apply_visibility shows it)."""
        import trimesh  # lazy: viser's own dependency, which writes the GLB it sends

        budget = self.budget()
        self.status.content = f"**mesh:** {len(mesh):,} triangles · {self.label} · decimating to {budget:,}…"
        shown = decimate(mesh, budget)
        session = self.app.session
        if session.has_gt:
            colors = session.gt_distance_colors(shown.vertices)
            scale = dataclasses.replace(session.cloud_scale(GT_DISTANCE),
                                        title="mesh: distance of its vertices to the nearest GT point")
            self.legend.content = scale_html(scale)
        else:
            colors = shown.vertex_colors
            self.legend.content = note_html("mesh: colours of the images (no GT points to colour a distance by)")
        rgba = np.concatenate([colors, np.full((len(colors), 1), 255, np.uint8)], axis=1)
        surface = trimesh.Trimesh(np.asarray(shown.vertices, np.float32), np.asarray(shown.triangles, np.int64),
                                  vertex_normals=shown.vertex_normals, vertex_colors=rgba, process=False)
        # no shadows: in software WebGL they cost most of a frame (tiny's Poisson mesh at 200 000 triangles, a
        # canvas screenshot 48 s with viser's default shadows, 3.7 s without, once on a busy machine; not kept in
        # a result file)
        handle = self.app.server.scene.add_mesh_trimesh("/mesh", surface, visible=False, cast_shadow=False,
                                                        receive_shadow=False)
        self.sent = SentMesh(mesh, budget, shown, handle)
        reduced = f", {len(shown):,} sent (decimated)" if len(shown) < len(mesh) else ", all sent"
        self.status.content = f"**mesh:** {len(mesh):,} triangles{reduced} · {self.label}"

    def _score(self, mesh: TriangleMesh) -> None:
        """The whole mesh's scores against the scene's GT points into the Metrics folder (as deepc mesh)."""
        session = self.app.session
        if not session.has_gt:
            self.app.mesh_metrics.content = "**mesh:** no GT points: no scores"
            return
        self.app.mesh_metrics.content = "**mesh:** scoring…"
        run = session.run
        options = EvaluationOptions.from_dict((run.options.get("evaluation") if run is not None else None) or {})
        evaluation = evaluate_mesh(session.scene, mesh, options).to_dict()
        if self.mesh is mesh:  # (a newer mesh came meanwhile: its own scoring follows)
            self.app.mesh_metrics.content = mesh_scores_text(evaluation)

    def apply_visibility(self) -> None:
        """Draw the cloud, the mesh or both, as the Show dropdown says; a mesh not sent yet (or sent for another
        budget) is queued for the sender and the cloud stays until it arrives."""
        wanted = self._wanted()
        if wanted and self._needs_send():
            self.sender.submit(None)
        handle = self.handle
        if handle is not None:
            handle.visible = wanted
        if self.app.cloud_handle is not None:
            self.app.cloud_handle.visible = str(self.show.value) in ("cloud", "cloud + mesh") or handle is None

    def glb_triangles(self) -> int:
        """Triangles in the GLB the scene holds for the mesh (read back as the browser gets it; 0 before one)."""
        import trimesh  # lazy: viser's own dependency

        handle = self.handle
        if handle is None:
            return 0
        data = handle._impl.props.glb_data  # viser 1.1's GlbHandle: the bytes sent to every client
        return len(trimesh.load(io.BytesIO(data), file_type="glb", force="mesh").faces)

    def stop(self) -> None:
        self.worker.stop(timeout=10)
        self.sender.stop(timeout=10)
