"""Every view's PatchMatch state at the start of each pass, kept on disk after a first replay for the pixel probe.

The first probe of a view replays the view through every level and pass (``engine.run.probe``); its state at the
start of each pass (depth and normal: a pass recomputes costs and selected views from them), at the end of each
level, and how many iterations each pass ran (a converged pass ends by the whole level's counts) go to
``OUT/history/states/view<i>.npz`` (written atomically, float32 maps packed losslessly as the pass history
packs depth). A later probe of another pixel of the view, in this process or another, starts every pass from
them and replays only the pixels the probed ones depend on (``engine.patchmatch.probe.partial``).

The file is keyed on what determines the replay: the pass history's inputs fingerprint (scene, options, code
version), the view, the history's snapshot files and the view's depth map as the run wrote it; any change makes
it stale (read as missing, then overwritten). The folder is bounded: after every write the least recently used
files (by modification time, which a read refreshes) are removed until it holds at most ``cap_bytes``.

Size: 16 bytes per pixel per pass start and level end, times about 0.7 after packing, 1 + geom_passes + 1
states per level: 5.7 MB per view of fountain_p11 at 384x256 (3 levels, 2 geometric passes; measured by
``benchmarks/performance/inspector_latency.py``), about 23 MB at 768x512.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from engine.io.atomic import atomic_write_bytes
from engine.run.pass_history import pack_depth, unpack_depth

STATES_DIR = "states"  # inside the run's history folder
DEFAULT_CAP_BYTES = 1 << 30
_FORMAT = 1


@dataclasses.dataclass
class ViewStates:
    """One view's replay as the probe needs it again.

    Attributes:
        states: (level, pass) -> (depth (H, W) f32, normal (H, W, 3) f32) at the start of that pass, and
            (level, "end") -> the same after the level's last pass; H, W the level's size.
        iterations: (level, pass) -> red-black iterations the pass ran.
    """

    states: dict[tuple[int, Any], tuple[np.ndarray, np.ndarray]]
    iterations: dict[tuple[int, int], int]


def replay_key(history_key: str, view: int, depth_map: np.ndarray, snapshot_files: list[Path]) -> str:
    """SHA-256 of what a view's replay depends on: the history's inputs fingerprint, the view index, the run's
    depth map of the view (the replay must end on it) and the history's snapshot files (name, size, mtime)."""
    digest = hashlib.sha256()
    stats = []
    for p in sorted(snapshot_files):
        st = p.stat()
        stats.append([p.name, st.st_size, st.st_mtime_ns])
    digest.update(json.dumps({"format": _FORMAT, "history": history_key, "view": int(view), "snapshots": stats},
                             sort_keys=True).encode())
    digest.update(np.ascontiguousarray(depth_map, np.float32).tobytes())
    return digest.hexdigest()


def _tag(key: tuple[int, Any]) -> str:
    return f"L{key[0]}_P{key[1]}"


class StateStore:
    """The pass-start states of a run's views in ``folder`` (module doc), at most ``cap_bytes`` on disk."""

    def __init__(self, folder: str | Path, cap_bytes: int = DEFAULT_CAP_BYTES):
        self.folder = Path(folder)
        self.cap_bytes = int(cap_bytes)

    def path(self, view: int) -> Path:
        return self.folder / f"view{int(view)}.npz"

    def load(self, view: int, key: str) -> ViewStates | None:
        """View ``view``'s states if stored under ``key`` (None if missing, stale or unreadable); a read marks the
        file as recently used."""
        path = self.path(view)
        try:
            with np.load(path) as data:
                meta = json.loads(bytes(data["meta"]).decode())
                if meta.get("format") != _FORMAT or meta.get("key") != key:
                    return None
                states = {}
                for level, p in meta["states"]:
                    tag = _tag((level, p))
                    states[(level, p)] = (unpack_depth(data[f"{tag}_z"], data[f"{tag}_zs"]),
                                          unpack_depth(data[f"{tag}_n"], data[f"{tag}_ns"]))
            iterations = {(int(lv), int(p)): int(n) for lv, p, n in meta["iterations"]}
        except (OSError, KeyError, ValueError, TypeError, zlib.error):
            return None
        try:
            os.utime(path)  # least recently used = oldest modification time
        except OSError:
            pass
        return ViewStates(states, iterations)

    def save(self, view: int, key: str, states: ViewStates) -> None:
        """Store view ``view``'s states under ``key`` (atomically), then trim the folder to ``cap_bytes``."""
        arrays: dict[str, np.ndarray] = {}
        for k, (depth, normal) in states.states.items():
            tag = _tag(k)
            arrays[f"{tag}_z"], arrays[f"{tag}_zs"] = pack_depth(depth)
            arrays[f"{tag}_n"], arrays[f"{tag}_ns"] = pack_depth(normal)
        meta = {"format": _FORMAT, "key": key, "states": [list(k) for k in states.states],
                "iterations": [[lv, p, n] for (lv, p), n in sorted(states.iterations.items())]}
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        atomic_write_bytes(self.path(view), buffer.getvalue())
        self.trim()

    def trim(self) -> None:
        """Remove the least recently used files until the folder holds at most ``cap_bytes``."""
        files = []
        for p in self.folder.glob("view*.npz"):
            try:
                st = p.stat()
            except OSError:
                continue
            files.append((st.st_mtime_ns, st.st_size, p))
        total = sum(f[1] for f in files)
        for _, size, p in sorted(files):
            if total <= self.cap_bytes:
                break
            p.unlink(missing_ok=True)
            total -= size

    def size_bytes(self) -> int:
        """Bytes on disk."""
        return sum(p.stat().st_size for p in self.folder.glob("view*.npz"))
