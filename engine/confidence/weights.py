"""Weights files of the confidence network.

A weights file is a ``torch.save`` dict: ``format`` (:data:`FORMAT`), ``version``, ``architecture``
(what :class:`ConfidenceNet` was built with), ``state_dict`` (fp16 to keep the shipped file under
20 MB; parameters are cast back to fp32 on load) and free-form ``meta`` (training options, validation
AUC, date). Every problem loading one is a one-line :class:`DeepCError` naming the file.
"""

from __future__ import annotations

import io
import pickle
import zipfile
from pathlib import Path
from typing import Any

import torch

from engine.confidence.network import FUSIONS, ConfidenceNet
from engine.errors import DeepCError
from engine.io.atomic import atomic_write_bytes

FORMAT = "deepc-confidence-weights"
VERSION = 1
DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "deepc_middle.pt"


def save_weights(path: str | Path, model: ConfidenceNet, meta: dict[str, Any] | None = None,
                 half: bool = True) -> Path:
    """Write ``model`` (fp16 floats when ``half``) with its architecture and ``meta`` atomically."""
    state = {k: (v.half() if half and v.is_floating_point() else v).clone() for k, v in model.state_dict().items()}
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION, "architecture": model.architecture,
                "state_dict": state, "meta": meta or {}}, buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return Path(path)


def read_weights_file(path: str | Path) -> dict[str, Any]:
    """The checked contents of a weights file (see module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise DeepCError("confidence weights file not found", path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile, pickle.UnpicklingError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DeepCError(f"not a readable weights file (corrupt or truncated: {first[:120]})", path) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise DeepCError(f"not a DeepC confidence weights file (no '{FORMAT}' header)", path)
    if data.get("version") != VERSION:
        raise DeepCError(f"weights format version {data.get('version')!r}, this program reads {VERSION}", path)
    return data


def build_model(architecture: dict[str, Any], path: str | Path | None = None) -> ConfidenceNet:
    if architecture.get("name") != "deepc_unet" or architecture.get("fusion") not in FUSIONS:
        raise DeepCError(f"weights are for an unknown architecture {architecture!r}", path)
    return ConfidenceNet(architecture["fusion"], tuple(architecture.get("widths", ())))


def load_weights(path: str | Path | None = None, expect: dict[str, Any] | None = None) -> ConfidenceNet:
    """A :class:`ConfidenceNet` in eval mode with the weights of ``path`` (default: the shipped weights).

    ``expect``: architecture keys the file must have (e.g. ``{"fusion": "middle"}``)."""
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    data = read_weights_file(path)
    arch = data.get("architecture") or {}
    for key, value in (expect or {}).items():
        if arch.get(key) != value:
            raise DeepCError(f"weights are for architecture {key}={arch.get(key)!r}, expected {value!r}", path)
    try:
        model = build_model(arch, path)
    except (TypeError, ValueError) as exc:
        raise DeepCError(f"weights describe an invalid architecture {arch!r} ({exc})", path) from None
    state = {k: v.float() if v.is_floating_point() else v for k, v in data["state_dict"].items()}
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        missing = str(exc).splitlines()[0][:160]
        raise DeepCError(f"weights do not fit the {arch.get('fusion')} network they claim to be ({missing})",
                         path) from None
    model.eval()
    model.meta = data.get("meta", {})
    return model
