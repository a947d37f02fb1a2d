"""What the viewer's Export panel writes: the current cloud as PLY, or its state as a rerun recording.

Files go to OUT/exports/ under a name from the GUI that is sanitised first (:func:`safe_file_name`), so a
name typed in a browser can never write outside that folder.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from engine.fusion import FusedCloud
from engine.io.ply import write_ply
from engine.scene import Scene
from workbench.rerun.options import StreamOptions
from workbench.viewer.session import ViewParams


def safe_file_name(text: str, suffix: str) -> str:
    """A file name made only of [A-Za-z0-9._-], never a path: names from the GUI cannot escape the folder."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(text).name).strip("._") or "export"
    return stem[:80] + suffix


def write_cloud_ply(path: Path, cloud: FusedCloud) -> None:
    """The cloud with normals, colours and its points' numbers of supporting views."""
    write_ply(path, np.asarray(cloud.xyz), cloud.normal, cloud.rgb,
              extra={"num_views": cloud.num_views.astype(np.int32)})


def write_state_rrd(path: Path, scene: Scene, cloud: FusedCloud, params: ViewParams, point_size: float, view: int,
                    images: dict[str, np.ndarray]) -> None:
    """A recording of the cameras, the maps ``images`` of view ``view``, the cloud and the parameters."""
    import rerun as rr  # lazy: rerun

    from workbench.rerun.recording import Recording  # lazy: rerun
    from workbench.rerun.stream import RerunStream  # lazy: rerun

    recording = Recording(path)
    try:
        views = [(v.name, v.camera, scene.image(v.index), v.source_views) for v in scene.views]
        stream = RerunStream(recording.rec, views, options=StreamOptions(max_points=0))  # an export keeps every point
        stream.log_cloud(str(params.pipeline), np.asarray(cloud.xyz, np.float32), cloud.rgb, radius=point_size / 2)
        for kind, image in images.items():
            stream.log_view_map(view, kind, image)
        recording.rec.log("params", rr.TextDocument(str(dataclasses.asdict(params))), static=True)
    except BaseException:
        recording.abandon()
        raise
    recording.finish()
