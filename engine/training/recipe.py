"""Training recipes: the scenes, their split and the training options of one set of shipped weights.

A recipe is a TOML file that ``deepc train --recipe FILE`` turns into weights. It names every scene with
its split (``train`` / ``validation`` / ``test``, chosen before training), the engine runs that make the
training maps, and the :class:`TrainOptions`. Scene entries are paths relative to the data root
(``--data DIR``, default the recipe's ``[data] root`` relative to the current directory), tables with a
``path`` and per-scene engine options, or ``synthetic:SEEDS`` (rendered by :mod:`engine.synthetic.dataset`).

Example::

    [recipe]
    name = "deepc_middle"                   # weights are written as <name>.pt

    [data]
    root = "../shared/data"
    groups = [["Piano", "PianoL"]]           # variants of one scene: never in two splits

    [engine]                                 # engine runs of every scene (cached, reused while options match)
    schedule = "acmm"
    num_source_views = 4

    [split]
    train = ["middlebury_2014q/ArtL", "hololens_000", "synthetic:0-7"]
    validation = ["middlebury_2014q/Recycle"]
    test = [{ path = "fountain_p11", max_image_size = 768, num_source_views = 5 }]
    real_share = 0.6                         # fraction of training crops drawn from real (non-synthetic) views

    [training]                               # TrainOptions fields
    epochs = 10

    [refined]                                # network 2 only: learn on refined maps (as --pipeline full makes
    weights = "engine/confidence/weights/deepc_middle.pt"   # them with this network 1 and these options)
    set = ["refinement.lambda_reg=7.5"]

``[refined] weights`` is relative to the current directory, like ``[data] root`` (run from the repository
root). ``[recipe] extends = "OTHER.toml"`` (relative to the recipe) takes the other recipe's sections and overrides
them key by key: the second network's recipe reuses the first's scenes and split that way.

Every problem (missing scene, a training or validation scene without GT depth, a scene in two splits, a
variant group split apart, an unknown key) is one :class:`DeepCError` naming the recipe file.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any

from engine.confidence.options import TrainOptions
from engine.core.errors import DeepCError, OptionsError

SPLITS = ("train", "validation", "test")
ENGINE_KEYS = {"schedule": str, "iterations": int, "num_source_views": int, "max_image_size": int}
SYNTHETIC_PREFIX = "synthetic:"


@dataclasses.dataclass(frozen=True)
class SceneEntry:
    """One scene of a recipe: a folder (or synthetic seed) and the engine options of its run."""

    name: str                   # unique within the recipe (folder name, or synth_NNNNN)
    path: Path | None           # scene folder; None for a synthetic seed not rendered yet
    seed: int | None            # synthetic seed, else None
    engine: dict[str, Any]      # schedule, iterations, num_source_views, max_image_size

    @property
    def synthetic(self) -> bool:
        return self.seed is not None

    @property
    def run_name(self) -> str:
        """Cache folder name of this scene's engine run (the options are part of it when they differ)."""
        size = self.engine.get("max_image_size", 0)
        return f"{self.name}_{size}px" if size else self.name


@dataclasses.dataclass
class Recipe:
    """A parsed, checked recipe (see the module docstring)."""

    path: Path
    name: str
    data_root: Path
    engine: dict[str, Any]
    splits: dict[str, list[SceneEntry]]
    real_share: float
    options: TrainOptions
    text: str                   # the file as written, copied into the model card
    refined: dict | None = None  # network 2: train on refined maps ([refined] weights = network 1, set = options)

    def scenes(self, split: str) -> list[SceneEntry]:
        return self.splits[split]


def parse_seeds(text: str) -> list[int]:
    """'0-59' or '1,2,5-9' -> list of ints (ValueError on anything else)."""
    seeds: list[int] = []
    for part in filter(None, text.replace(" ", "").split(",")):
        lo, dash, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi) + 1) if dash else [int(lo)])
    return seeds


def load_recipe(path: str | Path, data_root: str | Path | None = None) -> Recipe:
    """Read and check the recipe at ``path``; ``data_root`` overrides its ``[data] root``."""
    path = Path(path)
    raw, text = _read_toml(path)
    base = raw.get("recipe", {}).get("extends")
    if base is not None:  # another recipe's sections, overridden key by key by this one's
        base_path = path.parent / str(base)
        base_raw, base_text = _read_toml(base_path)
        if "extends" in base_raw.get("recipe", {}):
            raise DeepCError(f"[recipe] extends {base!r}, which extends another recipe (one level only)", path)
        raw = {section: {**base_raw.get(section, {}), **raw.get(section, {})} for section in {*base_raw, *raw}}
        text += f"\n# {base} (extended):\n{base_text}"
    unknown = set(raw) - {"recipe", "data", "engine", "split", "training", "refined"}
    if unknown:
        raise DeepCError(f"unknown recipe section(s) {', '.join(sorted(unknown))}", path)
    name = str(raw.get("recipe", {}).get("name", path.stem))
    data = raw.get("data", {})
    root = Path(data_root) if data_root is not None else Path(data.get("root", "."))
    engine = _engine_options(raw.get("engine", {}), path, "[engine]")
    split = dict(raw.get("split", {}))
    real_share = float(split.pop("real_share", 0.5))
    if not 0.0 <= real_share <= 1.0:
        raise DeepCError(f"[split] real_share={real_share} must be in [0, 1]", path)
    unknown = set(split) - set(SPLITS)
    if unknown:
        raise DeepCError(f"unknown split(s) {', '.join(sorted(unknown))} (splits: {', '.join(SPLITS)})", path)
    splits = {s: [e for item in _as_list(split.get(s, [])) for e in _entry(item, root, engine, path, s)]
              for s in SPLITS}
    if not splits["train"]:
        raise DeepCError("the recipe has no training scenes ([split] train)", path)
    _check_disjoint(splits, [list(g) for g in data.get("groups", [])], path)
    try:
        options = TrainOptions.from_dict(raw.get("training", {})).validate()
    except OptionsError as exc:
        raise DeepCError(f"[training] {exc}", path) from None
    except TypeError as exc:
        raise DeepCError(f"[training] {exc}", path) from None
    refined = raw.get("refined")
    if refined is not None:
        unknown = set(refined) - {"weights", "set"}
        if unknown or not isinstance(refined.get("weights", ""), str) or not isinstance(refined.get("set", []), list):
            raise DeepCError("[refined] takes weights = \"FILE.pt\" and set = [\"STAGE.NAME=VALUE\", ...]", path)
    return Recipe(path, name, root, engine, splits, real_share, options, text, refined)


def _read_toml(path: Path) -> tuple[dict[str, Any], str]:
    if not path.is_file():
        raise DeepCError("training recipe not found", path)
    text = path.read_text()
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise DeepCError(f"not a valid TOML recipe ({exc})", path) from None


def _as_list(value: Any) -> list:
    return value if isinstance(value, list) else [value]


def _engine_options(table: dict, path: Path, where: str) -> dict[str, Any]:
    out = {}
    for key, value in table.items():
        if key not in ENGINE_KEYS:
            raise DeepCError(f"{where}: unknown engine option {key!r} (known: {', '.join(ENGINE_KEYS)})", path)
        if not isinstance(value, ENGINE_KEYS[key]):
            raise DeepCError(f"{where}: {key} must be a {ENGINE_KEYS[key].__name__}, got {value!r}", path)
        out[key] = value
    if out.get("schedule", "acmm") not in ("acmm", "paper"):
        raise DeepCError(f"{where}: schedule must be acmm or paper, got {out['schedule']!r}", path)
    return out


def _entry(item: Any, root: Path, engine: dict, path: Path, split: str) -> list[SceneEntry]:
    """The scene(s) of one ``[split]`` item, checked to exist and (train, validation) to have GT depth."""
    from engine.synthetic.dataset import training_scene_name  # lazy: pycolmap (synthetic scene export)

    if isinstance(item, str) and item.startswith(SYNTHETIC_PREFIX):
        try:
            seeds = parse_seeds(item[len(SYNTHETIC_PREFIX):])
        except ValueError:
            raise DeepCError(f"[split] {split}: {item!r}: seeds must look like synthetic:0-7 or "
                             "synthetic:1,2,5", path) from None
        return [SceneEntry(training_scene_name(s), None, s, dict(engine)) for s in seeds]
    if isinstance(item, dict):
        item = dict(item)
        rel = item.pop("path", None)
        if not isinstance(rel, str):
            raise DeepCError(f"[split] {split}: a scene table needs a 'path' string", path)
        options = {**engine, **_engine_options(item, path, f"[split] {split} {rel}")}
    elif isinstance(item, str):
        rel, options = item, dict(engine)
    else:
        raise DeepCError(f"[split] {split}: {item!r} is neither a scene path nor a table", path)
    folder = root / rel
    if not folder.is_dir():
        raise DeepCError(f"[split] {split}: scene {rel!r} not found under {root}", path)
    if split != "test" and not (folder / "ground_truth" / "depth_maps").is_dir():
        raise DeepCError(f"[split] {split}: scene {rel!r} has no ground-truth depth maps "
                         "(ground_truth/depth_maps/): it cannot give labels", path)
    return [SceneEntry(folder.resolve().name, folder, None, options)]


def _check_disjoint(splits: dict[str, list[SceneEntry]], groups: list[list[str]], path: Path) -> None:
    where: dict[str, str] = {}
    for split, entries in splits.items():
        for e in entries:
            if e.name in where and where[e.name] != split:
                raise DeepCError(f"scene {e.name} is in both the {where[e.name]} and the {split} split", path)
            if e.name in where:
                raise DeepCError(f"scene {e.name} is named twice in the {split} split", path)
            where[e.name] = split
    for group in groups:
        used = {where[n] for n in group if n in where}
        if len(used) > 1:
            raise DeepCError(f"variants {', '.join(group)} of one scene are split across {', '.join(sorted(used))}",
                             path)
