"""Weights files of the confidence network.

A weights file is a ``torch.save`` dict: ``format`` (:data:`FORMAT`), ``version``, ``architecture``
(what :class:`ConfidenceNet` was built with), ``state_dict`` (fp16 to keep the shipped file under
20 MB; parameters are cast back to fp32 on load) and free-form ``meta`` (training options, validation
AUC, date). Every problem loading one is a one-line :class:`DeepCError` naming the file.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any

import torch

from engine.confidence.network import FUSIONS, ConfidenceNet
from engine.core.errors import DeepCError
from engine.io.atomic import atomic_write_bytes

FORMAT = "deepc-confidence-weights"
VERSION = 1
DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "deepc_middle.pt"
# the second network (Kuhn et al. 2020, §4.2): confidence of refined maps in --pipeline full
DEFAULT_REFINED_WEIGHTS = Path(__file__).resolve().parent / "weights" / "deepc_refined.pt"


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
        with warnings.catch_warnings():  # e.g. "pickle protocol 0" for damaged files: the error below says it
            warnings.simplefilter("ignore")
            data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001  torch's unpickler raises anything (IndexError, KeyError, ...) on damage
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DeepCError(f"not a readable weights file (corrupt or truncated: {first[:120]})", path) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise DeepCError(f"not a DeepC confidence weights file (no '{FORMAT}' header)", path)
    if data.get("version") != VERSION:
        raise DeepCError(f"weights format version {data.get('version')!r}, this program reads {VERSION}", path)
    state = data.get("state_dict")
    if not isinstance(state, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                              for k, v in state.items()):
        raise DeepCError("damaged weights file: 'state_dict' is not a table of named tensors", path)
    if not isinstance(data.get("architecture"), dict):
        raise DeepCError("damaged weights file: 'architecture' is not a table", path)
    return data


MAX_WIDTH = 4096  # channels per level; far above any trained network, and bounds what a damaged file allocates


def build_model(architecture: dict[str, Any], path: str | Path | None = None) -> ConfidenceNet:
    if architecture.get("name") != "deepc_unet" or architecture.get("fusion") not in FUSIONS:
        raise DeepCError(f"weights are for an unknown architecture {architecture!r}", path)
    widths = architecture.get("widths", ())
    if (not isinstance(widths, (list, tuple)) or not 1 <= len(widths) <= 8
            or not all(isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= MAX_WIDTH for w in widths)):
        raise DeepCError(f"weights describe invalid level widths {widths!r} (1 to 8 levels of 1..{MAX_WIDTH})", path)
    return ConfidenceNet(architecture["fusion"], tuple(architecture.get("widths", ())))


def load_weights(path: str | Path | None = None, expect: dict[str, Any] | None = None) -> ConfidenceNet:
    """A :class:`ConfidenceNet` in eval mode with the weights of ``path`` (default: the shipped weights).

    ``expect``: architecture keys the file must have (e.g. ``{"fusion": "middle"}``)."""
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    data = read_weights_file(path)
    arch = data["architecture"]
    for key, value in (expect or {}).items():
        if arch.get(key) != value:
            raise DeepCError(f"weights are for architecture {key}={arch.get(key)!r}, expected {value!r}", path)
    try:
        model = build_model(arch, path)
    except (TypeError, ValueError) as exc:
        raise DeepCError(f"weights describe an invalid architecture {arch!r} ({exc})", path) from None
    state = data["state_dict"]
    broken = next((k for k, v in state.items() if v.is_floating_point() and not torch.isfinite(v).all()), None)
    if broken is not None:  # flipped bits in the stored numbers: the network would predict NaN everywhere
        raise DeepCError(f"damaged weights file: tensor {broken!r} holds NaN or infinite values", path)
    state = {k: v.float() if v.is_floating_point() else v for k, v in state.items()}
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        missing = str(exc).splitlines()[0][:160]
        raise DeepCError(f"weights do not fit the {arch.get('fusion')} network they claim to be ({missing})",
                         path) from None
    model.eval()
    model.meta = data.get("meta", {})
    return model
