"""The pass history of a run: what one view's PatchMatch needs, besides its own inputs, to be re-run alone.

A view's PatchMatch is a deterministic function of its images, its cameras, the options and, in geometric
passes, the depth maps of its source views after the previous pass (random numbers are keyed by seed, view,
level, pass, iteration and colour: ``patchmatch/rng.py``). The history keeps exactly those depth snapshots:
``OUT/history/L{level}_P{pass}.npz`` holds every view's depth map (float32, losslessly packed by
``engine.io.packing.pack_float32``, key = view index) as
the geometric pass ``pass`` of ``level`` read it, and ``OUT/history/manifest.json`` the fingerprint of the
inputs (``checkpoint.inputs_fingerprint``) and the passes present. With it the pixel probe runs on demand on a
finished run and a region re-run starts from the exact state a pass started from (``engine.run.probe``);
replaying the view gives the stored maps bit for bit.

Size: one float32 depth map per view, level and geometric pass (docs/probe_schema.md has the numbers).
"""

from __future__ import annotations

import io
import json
import shutil
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from engine.core.errors import DeepCError
from engine.io.atomic import atomic_write_bytes, atomic_write_text
from engine.io.packing import pack_float32, unpack_float32
from engine.run.checkpoint import inputs_fingerprint
from engine.run.probe_states import STATES_DIR, RunStates, StateStore, replay_key

HISTORY_DIR = "history"
_FORMAT = 1


class PassHistory:
    """The depth snapshots of a run's geometric passes in ``folder`` (module doc).

    ``run_patchmatch(..., history=h)`` writes through :meth:`bind` and :meth:`save_snapshot`; a later
    process reads with :meth:`open` and :meth:`load_snapshot`."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.key: str | None = None
        self.passes: list[tuple[int, int]] = []
        self.n_views = 0
        # every view's pass-start states, recorded by the run for the probe (engine.run.probe_states)
        self.states = RunStates(StateStore(self.folder / STATES_DIR))

    @property
    def manifest_path(self) -> Path:
        return self.folder / "manifest.json"

    @staticmethod
    def _name(level: int, pass_index: int) -> str:
        return f"L{level}_P{pass_index}.npz"

    def bind(self, views: list[Any], options: Any, n_levels: int) -> None:
        """Attach to a run: keep the snapshots of an earlier (interrupted) run with the same inputs, else start
        empty."""
        key = inputs_fingerprint(views, options, n_levels)
        manifest = self._read_manifest()
        if manifest is not None and manifest.get("key") == key:
            self.passes = [tuple(p) for p in manifest.get("passes", [])]
        else:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.passes = []
        self.key, self.n_views = key, len(views)
        self.states.clear()
        self._write_manifest()

    def save_snapshot(self, level: int, pass_index: int, depths: list[np.ndarray]) -> None:
        """Store every view's depth map that geometric pass ``pass_index`` of ``level`` reads."""
        buffer = io.BytesIO()
        arrays = {}
        for i, d in enumerate(depths):
            arrays[str(i)], arrays[f"{i}_shape"] = pack_float32(d)
        np.savez(buffer, **arrays)
        atomic_write_bytes(self.folder / self._name(level, pass_index), buffer.getvalue())
        if (level, pass_index) not in self.passes:
            self.passes.append((level, pass_index))
        self._write_manifest()

    def _read_manifest(self) -> dict | None:
        try:
            data = json.loads(self.manifest_path.read_text())
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) and data.get("format") == _FORMAT else None

    def _write_manifest(self) -> None:
        atomic_write_text(self.manifest_path, json.dumps(
            {"format": _FORMAT, "key": self.key, "views": self.n_views, "passes": [list(p) for p in self.passes]},
            indent=1))

    # ---- reading ----------------------------------------------------------------------------------
    def open(self, views: list[Any], options: Any, n_levels: int, needed: list[tuple[int, int]]) -> None:
        """Check that the history belongs to these inputs and holds the ``needed`` (level, pass) snapshots;
        a one-line :class:`DeepCError` otherwise."""
        manifest = self._read_manifest()
        if manifest is None:
            raise DeepCError("the run has no pass history (runs made before it existed, or with --no-history): "
                             "re-run it to probe it", self.folder)
        if manifest.get("key") != inputs_fingerprint(views, options, n_levels):
            raise DeepCError("the pass history belongs to other inputs (the scene or the options changed since "
                             "the run)", self.folder)
        self.key = manifest["key"]
        self.passes = [tuple(p) for p in manifest.get("passes", [])]
        missing = [p for p in needed if p not in self.passes]
        if missing:
            raise DeepCError(f"the pass history lacks the snapshots of (level, pass) {missing} (an interrupted "
                             "or resumed run)", self.folder)

    def load_snapshot(self, level: int, pass_index: int, indices: list[int]) -> dict[int, np.ndarray]:
        """The depth maps of views ``indices`` that geometric pass ``pass_index`` of ``level`` read."""
        path = self.folder / self._name(level, pass_index)
        try:
            with np.load(path) as data:
                return {i: unpack_float32(data[str(i)], data[f"{i}_shape"]) for i in indices}
        except (OSError, KeyError, ValueError, zlib.error) as exc:
            raise DeepCError(f"unreadable pass-history snapshot ({exc})", path) from None

    def view_key(self, view: int, depth: np.ndarray) -> str | None:
        """The key of view ``view``'s probe states (``probe_states.replay_key``) given its depth map as the run
        wrote it; None before :meth:`bind` or :meth:`open`."""
        if self.key is None:
            return None
        return replay_key(self.key, view, depth, sorted(self.folder.glob("L*_P*.npz")))

    def size_bytes(self) -> int:
        """Bytes on disk."""
        return sum(p.stat().st_size for p in self.folder.rglob("*") if p.is_file())
