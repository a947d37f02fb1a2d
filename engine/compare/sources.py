"""The runs a comparison reads: our run folders and, read-only, the depth maps of other MVS systems.

- a deepc run (``metrics.json``): the maps its pipeline fused (``engine.run.fused_maps``), or its PatchMatch
  depth maps (``maps="raw"``); its fused cloud ``fused.ply``; its scene is the one the run used.
- a COLMAP dense workspace (``stereo/depth_maps/<image>.{geometric,photometric}.bin``, ``engine.io.dense``): the
  geometric map of an image where there is one, else the photometric one; ``fused.ply`` when stereo_fusion wrote
  it; its undistorted ``sparse/`` and ``images/`` make it a scene of its own.
- an OpenMVS densify folder (``depthNNNN.dmap``, :mod:`engine.compare.dmap`): each file names its image; the dense
  cloud is ``*_dense.ply`` (or ``fused.ply``); a folder with the COLMAP scene it came from (``sparse/``,
  ``images/``) is a scene too.

A :class:`SourceRun` lists its depth maps by the image name it stores (``keys``) and reads one (:meth:`depth`) at
the size the run made it. A folder of none of these kinds, or one with a malformed map, is a one-line
:class:`DeepCError` naming the file, found when the run is opened (headers are read then, maps when compared).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine.compare.dmap import read_dmap
from engine.core.errors import DeepCError
from engine.io.dense import read_dense_map_header, read_depth_map, read_normal_map
from engine.run.folder import map_path, read_map, read_run_metrics, run_scene
from engine.run.fused_maps import FusionRule, fused_view, read_run_view

KINDS = ("deepc", "colmap", "openmvs")
MAPS = ("fused", "raw")
COLMAP_DEPTH = Path("stereo") / "depth_maps"
COLMAP_TYPES = ("geometric", "photometric")  # preferred first
#: DensifyPointCloud's final maps; mid-run it also writes depthNNNN.geo.dmap (geometric passes) and
#: depthNNNN.filtered.dmap (another format), which an interrupted run leaves behind
DMAP_NAME = re.compile(r"depth\d+\.dmap")


@dataclasses.dataclass
class SourceRun:
    """One side of a comparison.

    Attributes:
        path: the folder given; kind: one of :data:`KINDS`; description: one line for tables ("deepc vanilla",
            "COLMAP geometric", ...).
        keys: image name as the run stores it -> what :attr:`read` takes for it.
        sizes: image name as stored -> (width, height) of its depth map, pixels.
        fused: the run's fused cloud (PLY), or None.
        scene_root: a folder :func:`engine.scene.load_scene` reads for this run (None: the run names no scene).
        scene_options: the scene options the run used (deepc runs), else empty.
        read: key -> (H, W) float32 depth, camera-frame z in scene units, 0 = none.
        read_normal: key -> (H, W, 3) float32 camera-frame unit normals facing the camera (0 = none); a
            :class:`DeepCError` when the run has none.
    """

    path: Path
    kind: str
    description: str
    keys: dict[str, str]
    sizes: dict[str, tuple[int, int]]
    fused: Path | None
    scene_root: Path | None
    scene_options: dict = dataclasses.field(default_factory=dict)
    read: Callable[[str], np.ndarray] = dataclasses.field(repr=False, default=lambda key: np.zeros((0, 0)))
    read_normal: Callable[[str], np.ndarray] = dataclasses.field(repr=False, default=lambda key: np.zeros((0, 0)))

    def depth(self, name: str) -> np.ndarray:
        """(H, W) float32 depth of the image stored as ``name`` (a key of :attr:`keys`), 0 = none."""
        return self.read(self.keys[name])

    def normal(self, name: str) -> np.ndarray:
        """(H, W, 3) float32 camera-frame normals of the image stored as ``name``, at its depth map's size."""
        return self.read_normal(self.keys[name])


def open_run(path: str | Path, maps: str = "fused") -> SourceRun:
    """The run in ``path``, whichever system made it; ``maps`` chooses a deepc run's maps (:data:`MAPS`)."""
    path = Path(path)
    if not path.exists():
        raise DeepCError("no such folder", path)
    if not path.is_dir():
        raise DeepCError("not a folder: give a deepc run, a COLMAP dense workspace or an OpenMVS densify folder", path)
    if (path / "metrics.json").is_file():
        return _deepc_run(path, maps)
    if (path / COLMAP_DEPTH).is_dir():
        return _colmap_run(path)
    if dmap_files(path):
        return _openmvs_run(path)
    raise DeepCError("not a deepc run (metrics.json), a COLMAP dense workspace (stereo/depth_maps/) or an OpenMVS "
                     "densify folder (depthNNNN.dmap)", path)


def _deepc_run(path: Path, maps: str) -> SourceRun:
    if maps not in MAPS:
        raise DeepCError(f"unknown maps {maps!r} (one of {', '.join(MAPS)})")
    metrics = read_run_metrics(path)
    scene = run_scene(path)
    index = {v.name: v.index for v in scene.views}
    missing = [v.name for v in scene.views if not map_path(path, "depth", v.name).is_file()]
    if missing:
        raise DeepCError(f"partial run: no depth map for {len(missing)} of {len(scene.views)} views "
                         f"({missing[0]}, ...)", path / "stereo" / "depth_maps")
    rule = FusionRule.from_saved(metrics.options, metrics.pipeline)

    def read_maps(name: str, kind: str) -> np.ndarray:
        if maps == "raw":
            return read_map(path, kind, name)
        return getattr(fused_view(scene, index[name], rule, read_run_view(path, name, rule.kinds())), kind)

    sizes = {v.name: v.camera.size for v in scene.views}
    fused = path / "fused.ply"
    return SourceRun(path, "deepc", f"deepc {metrics.pipeline}, {'fused' if maps == 'fused' else 'PatchMatch'} maps",
                     {n: n for n in index}, sizes, fused if fused.is_file() else None, Path(metrics.scene_path),
                     metrics.scene_options(), lambda name: read_maps(name, "depth"),
                     lambda name: read_maps(name, "normal"))


def _scene_folder(path: Path) -> Path | None:
    return path if (path / "sparse").is_dir() and (path / "images").is_dir() else None


def _colmap_run(path: Path) -> SourceRun:
    folder = path / COLMAP_DEPTH
    keys: dict[str, str] = {}
    for kind in reversed(COLMAP_TYPES):  # geometric overrides photometric
        for file in folder.rglob(f"*.{kind}.bin"):
            keys[file.relative_to(folder).as_posix()[:-len(f".{kind}.bin")]] = str(file)
    if not keys and any(folder.glob("*.bin")):  # our layout, stereo/depth_maps/<image>.bin, without metrics.json
        raise DeepCError("no metrics.json: an unfinished deepc run? (COLMAP's depth maps end in .geometric.bin or "
                         ".photometric.bin)", path)
    if not keys:
        raise DeepCError("a COLMAP workspace without depth maps (no *.geometric.bin or *.photometric.bin)", folder)
    sizes = {}
    for name, file in keys.items():
        width, height, channels = read_dense_map_header(file)
        if channels != 1:
            raise DeepCError(f"a depth map with {channels} channels", file)
        sizes[name] = (width, height)
    types = sorted({Path(f).suffixes[-2][1:] for f in keys.values()})
    fused = path / "fused.ply"
    return SourceRun(path, "colmap", f"COLMAP {'+'.join(types)}", keys, sizes, fused if fused.is_file() else None,
                     _scene_folder(path), {}, lambda file: read_depth_map(file, allow_nonfinite=True),
                     lambda file: _colmap_normal(path, Path(file)))


def _colmap_normal(path: Path, depth_file: Path) -> np.ndarray:
    """The normal map beside a COLMAP depth map (``stereo/normal_maps/``, the same name and type)."""
    normal_file = path / "stereo" / "normal_maps" / depth_file.relative_to(path / COLMAP_DEPTH)
    if not normal_file.is_file():
        raise DeepCError("no normal map beside the depth map (stereo/normal_maps/): our fusion needs one",
                         normal_file)
    return read_normal_map(normal_file)


def _dmap_normal(file: str) -> np.ndarray:
    normal = read_dmap(file).normal
    if normal is None:
        raise DeepCError("the depth map has no (float32) normal map: our fusion needs one", file)
    return np.where(np.isfinite(normal), normal, np.float32(0)).astype(np.float32)


def dmap_files(path: Path) -> list[Path]:
    """The final depth maps of an OpenMVS densify folder (``depthNNNN.dmap``, :data:`DMAP_NAME`), sorted."""
    return sorted(f for f in path.glob("depth*.dmap") if DMAP_NAME.fullmatch(f.name))


def _openmvs_run(path: Path) -> SourceRun:
    keys: dict[str, str] = {}
    sizes = {}
    for file in dmap_files(path):
        data = read_dmap(file)
        name = data.image_name.replace("\\", "/")
        if name in keys:
            raise DeepCError(f"two depth maps of image {name} ({Path(keys[name]).name} and {file.name})", path)
        keys[name], sizes[name] = str(file), data.depth_size
    dense = sorted(path.glob("*_dense.ply")) or sorted(path.glob("fused.ply"))
    return SourceRun(path, "openmvs", "OpenMVS", keys, sizes, dense[0] if dense else None, _scene_folder(path), {},
                     lambda file: read_dmap(file).depth, _dmap_normal)


def match_names(stored: list[str], view_names: list[str]) -> dict[str, str]:
    """Scene view name -> stored image name, for the stored names that are one view's image: the same name, a path
    ending in ``/<name>`` (OpenMVS stores paths relative to its folder), or else the same file name when that
    is unique among the views."""
    views = set(view_names)
    by_basename: dict[str, list[str]] = {}
    for v in view_names:
        by_basename.setdefault(v.rsplit("/", 1)[-1], []).append(v)
    out: dict[str, str] = {}
    for key in stored:
        if key in views:
            out[key] = key
            continue
        parts = key.split("/")
        suffixes = ["/".join(parts[i:]) for i in range(1, len(parts))]
        match = next((s for s in suffixes if s in views), None)
        if match is None and len(by_basename.get(parts[-1], [])) == 1:
            match = by_basename[parts[-1]][0]
        if match is not None and match not in out:
            out[match] = key
    return out
