"""Every view's PatchMatch state at the start of each pass, kept on disk for the pixel probe.

``deepc run`` with its pass history records them as PatchMatch makes them (:class:`RunStates`); a run made
without them, or resumed, has them once a first probe of the view has replayed it whole (``engine.run.probe``).
Each view's state at the start of each pass (depth and normal: a pass recomputes costs and selected views from
them), at the end of each level, and how many iterations each pass ran (a converged pass ends by the whole
level's counts) go to ``OUT/history/states/view<i>.npz`` (written atomically, float32 maps packed losslessly,
``engine.io.packing``). A probe of a pixel of the view, in this process or another, starts every pass from them
and replays only the pixels the probed ones depend on (``engine.patchmatch.probe.partial``).

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
import shutil
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine.io.atomic import atomic_write_bytes
from engine.io.packing import pack_float32, unpack_float32

STATES_DIR = "states"  # inside the run's history folder
PARTS_DIR = "parts"  # inside STATES_DIR: the states a running PatchMatch has recorded so far
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
                    states[(level, p)] = (unpack_float32(data[f"{tag}_z"], data[f"{tag}_zs"]),
                                          unpack_float32(data[f"{tag}_n"], data[f"{tag}_ns"]))
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
            arrays.update(state_arrays(k, depth, normal))
        meta = {"format": _FORMAT, "key": key, "states": [list(k) for k in states.states],
                "iterations": [[lv, p, n] for (lv, p), n in sorted(states.iterations.items())]}
        self.write(view, arrays, meta)
        self.trim()

    def write(self, view: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        """Write view ``view``'s file from its packed ``arrays`` (:func:`state_arrays`) and ``meta``, atomically."""
        buffer = io.BytesIO()
        np.savez(buffer, **arrays, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
        atomic_write_bytes(self.path(view), buffer.getvalue())

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


def state_arrays(key: tuple[int, Any], depth: np.ndarray, normal: np.ndarray) -> dict[str, np.ndarray]:
    """The packed arrays of one state as a :class:`StateStore` file holds them."""
    tag = _tag(key)
    z, zs = pack_float32(depth)
    n, ns = pack_float32(normal)
    return {f"{tag}_z": z, f"{tag}_zs": zs, f"{tag}_n": n, f"{tag}_ns": ns}


class RunStates:
    """The pass-start states of every view, recorded while a run's PatchMatch makes them, so that the first probe
    of a view traces from them instead of replaying the whole view (module doc).

    ``engine.patchmatch.multiscale`` calls :meth:`begin` (not on a resumed run: its earlier passes are not
    recorded), :meth:`state` before each view's pass and after its level's last pass, and :meth:`ran` after the
    pass. Each state is packed and written at once under ``parts/`` (nothing accumulates in memory);
    :meth:`finish`, once the run has written its depth maps, turns each view's complete set of parts into its
    :class:`StateStore` file under the key a probe computes. Views whose states would not fit ``store.cap_bytes``
    are not recorded (a first probe then replays the view whole)."""

    def __init__(self, store: StateStore):
        self.store = store
        self.parts = store.folder / PARTS_DIR
        self.recording: set[int] = set()
        self.expected: list[tuple[int, Any]] = []
        self.iterations: dict[int, dict[tuple[int, int], int]] = {}

    def clear(self) -> None:
        """Drop the parts of an earlier, unfinished recording."""
        shutil.rmtree(self.parts, ignore_errors=True)
        self.recording.clear()
        self.iterations.clear()

    def begin(self, level_shapes: list[list[tuple[int, int]] | None], passes: int) -> None:
        """Record the views whose ``level_shapes`` (per view, (H, W) of each level; None for a view without
        PatchMatch) are given, ``passes`` passes per level, as many as fit ``store.cap_bytes``."""
        self.clear()
        n_levels = max((len(s) for s in level_shapes if s), default=0)
        self.expected = [(lv, p) for lv in range(n_levels) for p in range(passes)] + [(lv, "end") for lv in
                                                                                      range(n_levels)]
        budget = self.store.cap_bytes
        for i, shapes in enumerate(level_shapes):
            if not shapes:
                continue
            size = int(0.7 * 16 * (passes + 1) * sum(h * w for h, w in shapes))  # module doc: packed size
            if size > budget:
                break
            budget -= size
            self.recording.add(i)
            self.iterations[i] = {}

    def state(self, view: int, level: int, which: int | str, depth: np.ndarray, normal: np.ndarray) -> None:
        """Record view ``view``'s state at the start of pass ``which`` of ``level`` (or its end: ``"end"``)."""
        if view not in self.recording:
            return
        self.parts.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        np.savez(buffer, **state_arrays((level, which), depth, normal))
        atomic_write_bytes(self.parts / f"view{view}_{_tag((level, which))}.npz", buffer.getvalue())

    def ran(self, view: int, level: int, pass_index: int, iterations: int) -> None:
        """Record that pass ``pass_index`` of ``level`` ran ``iterations`` red-black iterations on view ``view``."""
        if view in self.iterations:
            self.iterations[view][(level, pass_index)] = iterations

    def finish(self, key_of: Callable[[int], str | None]) -> list[int]:
        """Store every recorded view whose states are complete under ``key_of(view)`` (None: skip it) and remove the
        parts; returns the views stored."""
        stored = []
        for view in sorted(self.recording):
            key = key_of(view)
            arrays: dict[str, np.ndarray] = {}
            try:
                for k in self.expected:
                    with np.load(self.parts / f"view{view}_{_tag(k)}.npz") as data:
                        arrays.update({name: data[name] for name in data.files})
            except (OSError, KeyError, ValueError):
                continue
            iterations = self.iterations.get(view, {})
            if key is None or any(k not in iterations for k in self.expected if k[1] != "end"):
                continue
            meta = {"format": _FORMAT, "key": key, "states": [list(k) for k in self.expected],
                    "iterations": [[lv, p, n] for (lv, p), n in sorted(iterations.items())]}
            self.store.write(view, arrays, meta)
            stored.append(view)
        self.clear()
        self.store.trim()
        return stored
