"""The output folder of ``deepc run`` (CONTRACT.md §4): per-view maps, metrics.json.

    OUT/stereo/{depth,normal,cost,counter,confidence}_maps/<name>.bin   COLMAP dense .bin
    OUT/refined/{depth,normal,counter,confidence}_maps/<name>.bin, OUT/refined/stamp.json
    OUT/fused.ply, OUT/metrics.json

Every file is written atomically, so an interrupted run never leaves a half-written map.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from engine.errors import DeepCError
from engine.io.atomic import atomic_write_text
from engine.io.dense import read_dense_map, write_dense_map

# kind -> (folder, channels)
MAP_KINDS = {
    "depth": ("stereo/depth_maps", 1),
    "normal": ("stereo/normal_maps", 3),
    "cost": ("stereo/cost_maps", 1),
    "counter": ("stereo/counter_maps", 1),
    "confidence": ("stereo/confidence_maps", 1),
    "refined_depth": ("refined/depth_maps", 1),
    "refined_normal": ("refined/normal_maps", 3),
    "refined_counter": ("refined/counter_maps", 1),  # counter maps of the refined maps (SPEC.md §6.6b)
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


def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as JSON atomically; numpy scalars become numbers and NaN/inf null (JSON has neither)."""
    path = Path(path)
    atomic_write_text(path, json.dumps(_json_safe(data), indent=2) + "\n")
    return path


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
