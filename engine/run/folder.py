"""The output folder of a run: its maps, its metrics and the stamp of its refined maps.

    RUN/stereo/{depth,normal,cost,counter,confidence}_maps/<name>.bin   COLMAP dense .bin
    RUN/refined/{depth,normal,counter,confidence}_maps/<name>.bin       refined maps (``--pipeline full``)
    RUN/refined/stamp.json                                              what the refined maps were made from
    RUN/fused.ply, RUN/metrics.json

The pipeline writes run folders; training, refinement of finished runs, the regression mode, its report and
the viewer read them, all through this module. Every file is written atomically, so an interrupted run never
leaves a half-written map.

The stamp's ``key`` holds everything that determines the refined maps: the SHA-256 of the network-1 weights
file, the options of confidence inference, refinement and counter maps, the scene and its options, a digest
of the run's own depth, normal and counter maps, and the engine version. Refined maps are reused only when
the stored key equals the new one and every map exists. The stamp is written last and removed before any
map is rewritten, so an interrupted refinement is never reused.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from engine import __version__
from engine.core.errors import DeepCError
from engine.core.interrupt import check_interrupt
from engine.io.atomic import write_json
from engine.io.dense import read_dense_map, write_dense_map
from engine.scene import Scene, SceneOptions, load_scene

# kind -> (folder, channels)
MAP_KINDS = {
    "depth": ("stereo/depth_maps", 1),
    "normal": ("stereo/normal_maps", 3),
    "cost": ("stereo/cost_maps", 1),
    "counter": ("stereo/counter_maps", 1),
    "confidence": ("stereo/confidence_maps", 1),
    "refined_depth": ("refined/depth_maps", 1),
    "refined_normal": ("refined/normal_maps", 3),
    "refined_counter": ("refined/counter_maps", 1),  # counter maps of the refined maps (Kuhn et al. 2020, §3.3)
    "refined_confidence": ("refined/confidence_maps", 1),  # their confidence (second network)
}


def map_path(out_dir: str | Path, kind: str, name: str) -> Path:
    """Path of the ``kind`` map of image ``name`` (names may contain '/')."""
    folder, _ = MAP_KINDS[kind]
    return Path(out_dir) / folder / f"{name}.bin"


def write_map(out_dir: str | Path, kind: str, name: str, array: np.ndarray) -> Path:
    path = map_path(out_dir, kind, name)
    write_dense_map(path, np.asarray(array, np.float32))
    return path


def read_map(out_dir: str | Path, kind: str, name: str) -> np.ndarray | None:
    """The map, or None when the run did not write it."""
    path = map_path(out_dir, kind, name)
    if not path.is_file():
        return None
    return read_dense_map(path, channels=MAP_KINDS[kind][1])


def write_metrics(out_dir: str | Path, metrics: dict[str, Any]) -> Path:
    """Write OUT/metrics.json atomically."""
    return write_json(Path(out_dir) / "metrics.json", metrics)


def read_metrics(out_dir: str | Path) -> dict[str, Any]:
    path = Path(out_dir) / "metrics.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise DeepCError("no metrics.json: not the output folder of a finished deepc run", path.parent) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DeepCError(f"malformed metrics.json ({exc})", path) from None


@dataclasses.dataclass
class RunMetrics:
    """metrics.json of a finished run, typed; keys a run did not write are None (or empty).

    Attributes:
        scene, scene_path: the scene's name and its folder (absolute, as the run saw it).
        pipeline: ``vanilla``, ``fast`` or ``full``.
        num_images, image_size: views and their working size (width, height) in pixels.
        seconds: wall-clock seconds per stage and ``total``.
        fused_points: points in ``fused.ply``.
        eval: ``{"tolerances", "accuracy", "completeness", "f1"}`` lists (percent), with GT points only.
        depth, refined_depth, full_depth: ``{"abs_rel", "within_1pct", "within_5pct", "valid_fraction"}`` of
            the PatchMatch, refined and fused-in maps against GT depth (percent; abs_rel a ratio).
        confidence_auc, refined_confidence_auc: ROC-AUC x 100 of the confidence maps against the labels.
        confidence_kept_pct: percent of the estimates the confidence filter kept.
        mesh: the mesh of ``RUN/mesh.ply`` (method, vertices, triangles, seconds, notes, options, ``eval``) when
            the run was meshed (``deepc run --mesh``, ``deepc mesh``).
        views: per view ``{"view", "pixels", "fused_pct", "confirmed_pct"}``: the share of its pixels that became
            fused points and that another view confirms (``engine.run.view_shares``); None in runs made before.
        options: ``PipelineOptions.to_dict()`` plus ``scene``: the options the run used.
        version: the engine version that wrote the run.
        extra: every other key (per-view lists, ``seconds_cpu`` of the regression mode, ...).
    """

    scene: str
    scene_path: str
    pipeline: str
    num_images: int = 0
    image_size: tuple[int, int] = (0, 0)
    seconds: dict[str, float] = dataclasses.field(default_factory=dict)
    fused_points: int = 0
    eval: dict[str, list[float]] | None = None
    depth: dict[str, float] | None = None
    refined_depth: dict[str, float] | None = None
    full_depth: dict[str, float] | None = None
    confidence_auc: float | None = None
    refined_confidence_auc: float | None = None
    confidence_kept_pct: float | None = None
    mesh: dict[str, Any] | None = None
    views: list[dict[str, Any]] | None = None
    options: dict[str, Any] = dataclasses.field(default_factory=dict)
    version: str = ""
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: dict[str, Any], path: str | Path = "metrics.json") -> RunMetrics:
        """Read the dict of a metrics.json; a missing scene or pipeline is a :class:`DeepCError` naming ``path``."""
        names = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        missing = [k for k in ("scene", "scene_path", "pipeline") if not data.get(k)]
        if missing:
            raise DeepCError(f"metrics.json has no {', '.join(missing)}: not written by a deepc run", path)
        known = {k: v for k, v in data.items() if k in names}
        if "image_size" in known:
            known["image_size"] = tuple(known["image_size"])
        return cls(**known, extra={k: v for k, v in data.items() if k not in names})

    def scene_options(self) -> dict[str, Any]:
        """The scene options the run used (``SceneOptions.from_dict`` input)."""
        return dict(self.options.get("scene") or {})


def read_run_metrics(out_dir: str | Path) -> RunMetrics:
    """:class:`RunMetrics` of the run in ``out_dir`` (one-line :class:`DeepCError` when absent or malformed)."""
    path = Path(out_dir) / "metrics.json"
    data = read_metrics(out_dir)
    if not isinstance(data, dict):
        raise DeepCError("malformed metrics.json (not a JSON object)", path)
    return RunMetrics.from_dict(data, path)


# --------------------------------------------------------------------------------------------
# Refined maps and their stamp.

STAMP = Path("refined") / "stamp.json"
#: refinement options that act only after the refined maps exist (filtering before fusion, sky filter)
POST_REFINEMENT = ("refined_confidence_tau", "sky_filter", "keep_confident", "sky")
#: confidence options that change the predicted values (tau and refined_weights act elsewhere)
INFERENCE = ("tile", "overlap", "bf16", "zero_backfacing")
#: the maps of a refined run that every refined run has (confidence only where a second network ran)
REFINED_KINDS = ("refined_depth", "refined_normal", "refined_counter")


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def maps_digest(names: list[str], depths: list[np.ndarray], normals: list[np.ndarray],
                counters: list[np.ndarray]) -> str:
    """Hex SHA-256 of the per-view input maps as float32 (what a run folder stores, so in-memory maps of a
    pipeline and the same maps read back from its folder give the same digest)."""
    digest = hashlib.sha256()
    for name, *arrays in zip(names, depths, normals, counters, strict=True):
        digest.update(name.encode("utf-8") + b"\0")
        for a in arrays:
            a = np.ascontiguousarray(a, np.float32)
            digest.update(repr(a.shape).encode() + a.tobytes())
    return digest.hexdigest()


def refinement_key(scene, weights_sha256: str, options, inputs_sha256: str) -> dict[str, Any]:
    """The stamp key (module doc); ``options`` is an :class:`engine.run.pipeline.PipelineOptions`."""
    confidence = options.confidence.to_dict()
    refinement = options.refinement.to_dict()
    key = {
        "scene_path": str(Path(scene.root).resolve()), "scene_options": scene.options.to_dict(),
        "inputs_sha256": inputs_sha256, "weights_sha256": weights_sha256,
        "confidence": {k: confidence[k] for k in INFERENCE},
        "refinement": {k: v for k, v in refinement.items() if k not in POST_REFINEMENT},
        "counter": options.counter.to_dict(), "engine_version": __version__,
    }
    return json.loads(json.dumps(key))  # tuples -> lists, as read back from the stamp


def read_stamp(run_dir: str | Path) -> dict[str, Any] | None:
    """The stamp of a run's refined maps; None when there is none or it is unreadable."""
    try:
        stamp = json.loads((Path(run_dir) / STAMP).read_text())
    except (OSError, ValueError):
        return None
    return stamp if isinstance(stamp, dict) and isinstance(stamp.get("key"), dict) else None


def refined_maps_complete(run_dir: str | Path, names: list[str], key: dict[str, Any]) -> bool:
    """Whether ``run_dir`` holds refined maps of every view made as ``key`` says."""
    stamp = read_stamp(run_dir)
    return stamp is not None and stamp["key"] == key and all(
        map_path(run_dir, kind, n).is_file() for n in names for kind in REFINED_KINDS)


def write_refined_maps(out_dir: str | Path, names: list[str], refined: list, counter: list[np.ndarray],
                       confidence: list[np.ndarray] | None = None) -> None:
    """Write the refined depth, normals, counter (and confidence) maps of every view; any stamp goes first."""
    (Path(out_dir) / STAMP).unlink(missing_ok=True)
    for i, name in enumerate(names):
        check_interrupt()  # between files only: a map is never left half-written
        write_map(out_dir, "refined_depth", name, refined[i].depth)
        write_map(out_dir, "refined_normal", name, refined[i].normal)
        write_map(out_dir, "refined_counter", name, counter[i])
        if confidence is not None:
            write_map(out_dir, "refined_confidence", name, confidence[i])


def write_stamp(out_dir: str | Path, key: dict[str, Any], weights: str | Path, seconds: dict[str, float]) -> Path:
    """Write RUN/refined/stamp.json (after every map)."""
    return write_json(Path(out_dir) / STAMP, {
        "format": "deepc-refined-maps", "key": key, "weights": str(Path(weights).resolve()),
        "seconds": seconds, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z")})


# --------------------------------------------------------------------------------------------
# A run's scene, and whether a run folder holds a finished run made with given options.

#: The option sections that determine a run's PatchMatch maps (depth, normal, counter).
MAP_SECTIONS = ("scene", "patchmatch", "counter")


def run_scene(run_dir: str | Path) -> Scene:
    """The scene of a run, loaded with the scene options the run used."""
    metrics = read_run_metrics(run_dir)
    return load_scene(metrics.scene_path, SceneOptions.from_dict(metrics.scene_options()))


def run_is_complete(run_dir: str | Path, scene_root: str | Path, expected_options: dict) -> bool:
    """Whether ``run_dir`` holds a finished run of ``scene_root`` whose options agree with
    ``expected_options`` in every section that determines the maps (:data:`MAP_SECTIONS`)."""
    try:
        metrics = read_run_metrics(run_dir)
    except DeepCError:
        return False
    if metrics.scene_path != str(Path(scene_root).resolve()):
        return False
    saved = json.loads(json.dumps(metrics.options or {}))
    expected = json.loads(json.dumps(expected_options))
    if any(saved.get(k) != expected.get(k) for k in MAP_SECTIONS):
        return False
    try:
        names = [v.name for v in run_scene(run_dir).views]
    except (DeepCError, KeyError, TypeError):
        return False
    return all(map_path(run_dir, kind, n).is_file() for n in names for kind in ("depth", "normal", "counter"))
