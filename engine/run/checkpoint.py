"""PatchMatch checkpoints: an interrupted ``deepc run`` resumes where it stopped, with identical results.

After each view finishes a pass (per level a photometric pass, then geometric passes; Xu & Tao 2019),
its maps (depth, normal, cost, selected views at that level's size) are written atomically to
``OUT/.deepc-resume/L{level}_P{pass}/{view}.npz`` and recorded, with their SHA-256, in
``OUT/.deepc-resume/manifest.json``, which also holds a hash of the PatchMatch options and a
fingerprint of the inputs (names, cameras, depth ranges, source views, grey images). A pass's files are
deleted once the next pass is complete, so at most two passes are on disk.

On resume every file is checked, not trusted: manifest key, checksum, array names, shapes, dtypes and
finite values. Anything that fails is recomputed (with a warning). The engine's random numbers are a
pure function of (seed, view, level, pass, iteration, pixel), so a resumed run gives byte-identical maps.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from engine import __version__
from engine.core.errors import DeepCError
from engine.io.atomic import atomic_write_bytes, atomic_write_text

CHECKPOINT_DIR = ".deepc-resume"
_FORMAT = 1
_ARRAYS = {"Z": (np.float32, 2), "N": (np.float32, 3), "C": (np.float32, 2), "S": (np.uint32, 2)}


@dataclasses.dataclass
class ResumeStats:
    """What a run took from its checkpoint."""

    reused: int = 0  # (view, pass) states loaded instead of computed
    rejected: int = 0  # states present but invalid (recomputed)
    saved: int = 0


def inputs_fingerprint(views: list[Any], options: Any, n_levels: int) -> str:
    """SHA-256 over everything a PatchMatch result depends on: the options and every view's inputs."""
    digest = hashlib.sha256()
    digest.update(json.dumps({"format": _FORMAT, "version": __version__, "levels": n_levels,
                              "options": options.to_dict()}, sort_keys=True, default=str).encode())
    for v in views:
        digest.update(json.dumps({"name": v.name, "camera": v.camera.to_dict(), "range": [v.depth_min, v.depth_max],
                                  "sources": list(v.source_views)}, sort_keys=True).encode())
        image = np.ascontiguousarray(v.image_gray, np.float32)
        digest.update(str(image.shape).encode())
        digest.update(image.tobytes())
    return digest.hexdigest()


class PatchMatchCheckpoint:
    """Per-view, per-pass PatchMatch states in ``folder``; see the module docstring.

    ``run_patchmatch(..., checkpoint=cp)`` calls :meth:`bind` once, then :meth:`load` / :meth:`save`
    per view and pass and :meth:`pass_complete` after each pass.
    """

    def __init__(self, folder: str | Path, resume: bool = True):
        self.folder = Path(folder)
        self.resume = resume
        self.key: str | None = None
        self.entries: dict[str, str] = {}  # relative file name -> sha256
        self.completed: list[tuple[int, int]] = []  # (level, pass) with every view saved
        self.stats = ResumeStats()
        self.note = ""  # what bind() found, for the user

    @property
    def manifest_path(self) -> Path:
        return self.folder / "manifest.json"

    # ---- set up ------------------------------------------------------------------------------------
    def bind(self, views: list[Any], options: Any, n_levels: int) -> None:
        """Attach to a run: keep the states of a matching earlier run (when resuming), else start empty."""
        key = inputs_fingerprint(views, options, n_levels)
        self.key = key
        manifest = self._read_manifest() if self.resume else None
        if manifest is not None and manifest.get("key") == key:
            self.entries = {k: v for k, v in manifest.get("files", {}).items() if isinstance(v, str)}
            self.completed = [tuple(p) for p in manifest.get("completed", []) if _is_pass(p)]
            self.note = f"resuming: {len(self.entries)} saved view states found in {self.folder}"
            return
        if manifest is not None:
            self.note = (f"{self.folder}: saved states belong to other inputs or options; "
                         "starting PatchMatch from the beginning")
            warnings.warn(self.note, stacklevel=2)
        elif self.resume and self.folder.exists():
            self.note = f"{self.folder}: no readable manifest; starting PatchMatch from the beginning"
            warnings.warn(self.note, stacklevel=2)
        elif self.resume:
            self.note = f"nothing to resume in {self.folder.parent}; starting from the beginning"
        elif self.manifest_path.is_file():
            self.note = (f"{self.folder}: discarding the saved states of an interrupted run "
                         "(deepc run --resume continues such a run)")
            warnings.warn(self.note, stacklevel=2)
        self.clear()
        self.key = key
        self._write_manifest()

    def _read_manifest(self) -> dict | None:
        try:
            data = json.loads(self.manifest_path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) and data.get("format") == _FORMAT else {}

    def _write_manifest(self) -> None:
        atomic_write_text(self.manifest_path, json.dumps(
            {"format": _FORMAT, "key": self.key, "completed": [list(p) for p in self.completed],
             "files": self.entries, "saved_by_this_run": self.stats.saved}, indent=1, sort_keys=True))

    # ---- per view and pass --------------------------------------------------------------------------
    @staticmethod
    def file_name(level: int, pass_index: int, view: int) -> str:
        """The file of ``view``'s state after pass ``pass_index`` of ``level``, relative to the folder."""
        return f"L{level}_P{pass_index}/{view}.npz"

    def resume_point(self) -> tuple[int, int] | None:
        """(level, pass) of the latest pass that every view completed, or None."""
        return self.completed[-1] if self.completed else None

    def load(self, level: int, pass_index: int, view: int, shape: tuple[int, int],
             reuse: bool = True) -> dict[str, np.ndarray] | None:
        """The saved state {Z, N, C, S} of ``view`` after pass ``pass_index`` of ``level``, verified; or None.
        ``reuse``: counted in ``stats.reused`` (False: a state this run saved and reads back, see
        ``engine.patchmatch.multiscale``)."""
        name = self.file_name(level, pass_index, view)
        expected = self.entries.get(name)
        if expected is None:
            return None
        try:
            data = (self.folder / name).read_bytes()
            if hashlib.sha256(data).hexdigest() != expected:
                raise ValueError("checksum mismatch")
            with np.load(io.BytesIO(data), allow_pickle=False) as archive:
                state = {k: archive[k] for k in _ARRAYS}
            for k, (dtype, ndim) in _ARRAYS.items():
                a = state[k]
                if a.dtype != dtype or a.ndim != ndim or a.shape[:2] != shape or (ndim == 3 and a.shape[2] != 3):
                    raise ValueError(f"{k} is {a.dtype} {a.shape}, expected {np.dtype(dtype)} {shape}")
                if a.dtype.kind == "f" and not np.isfinite(a).all():
                    raise ValueError(f"{k} has non-finite values")
        except Exception as exc:  # noqa: BLE001  (np.load raises assorted types on a damaged archive)
            self._reject(name, str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}")
            return None
        self.stats.reused += int(reuse)
        return state

    def _reject(self, name: str, reason: str) -> None:
        self.stats.rejected += 1
        self.entries.pop(name, None)
        warnings.warn(f"{self.folder / name}: saved state unusable ({' '.join(reason.split())[:120]}); "
                      "recomputing it", stacklevel=3)

    def save(self, level: int, pass_index: int, view: int, state: dict[str, np.ndarray]) -> None:
        """Write one view's state atomically, then record it in the manifest."""
        self.record(level, pass_index, view, write_state(self.folder, level, pass_index, view, state))

    def record(self, level: int, pass_index: int, view: int, sha256: str, write: bool = True) -> None:
        """Record a state :func:`write_state` wrote (here or in a per-view task elsewhere) in the manifest; with
        ``write`` False only in memory (the next record or :meth:`pass_complete` writes it: a driver of
        thousands of tasks need not rewrite the manifest after each)."""
        self.entries[self.file_name(level, pass_index, view)] = sha256
        self.stats.saved += 1
        if write:
            self._write_manifest()

    def flush(self) -> None:
        """Write the manifest with every state recorded so far (after ``record(..., write=False)``)."""
        self._write_manifest()

    def pass_complete(self, level: int, pass_index: int) -> None:
        """Every view finished this pass: record it and drop the states of older passes."""
        done = (level, pass_index)
        if done not in self.completed:
            self.completed.append(done)
        keep = {f"L{level}_P{pass_index}/"}
        stale = [name for name in self.entries if not any(name.startswith(k) for k in keep)]
        for name in stale:
            del self.entries[name]
        self.completed = [done]
        self._write_manifest()  # first forget, then delete: a kill in between leaves only unlisted files
        for folder in self.folder.glob("L*_P*"):
            if folder.is_dir() and f"{folder.name}/" not in keep:
                shutil.rmtree(folder, ignore_errors=True)

    # ---- end -----------------------------------------------------------------------------------------
    def clear(self) -> None:
        """Remove every saved state (the run finished, or they belong to other inputs)."""
        self.entries, self.completed = {}, []
        try:
            shutil.rmtree(self.folder)
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise DeepCError(f"cannot remove saved PatchMatch states: {exc.strerror or exc}", self.folder) from exc


def write_state(folder: str | Path, level: int, pass_index: int, view: int, state: dict[str, np.ndarray]) -> str:
    """Write one view's state {Z, N, C, S} after a pass atomically into the checkpoint ``folder`` (no manifest
    change: :meth:`PatchMatchCheckpoint.record` does that); returns the file's SHA-256."""
    buffer = io.BytesIO()
    np.savez(buffer, **{k: np.ascontiguousarray(state[k]) for k in _ARRAYS})
    data = buffer.getvalue()
    atomic_write_bytes(Path(folder) / PatchMatchCheckpoint.file_name(level, pass_index, view), data)
    return hashlib.sha256(data).hexdigest()


def _is_pass(value: Any) -> bool:
    return isinstance(value, list) and len(value) == 2 and all(isinstance(x, int) for x in value)
