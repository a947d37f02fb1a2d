"""The folds of benchmarks/paper/confidence_lofo.py: which scenes train, validate and test per held-out family; no
family in its own training or validation, variants of one scene together. No training, no engine run."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.training.recipe import SceneEntry
from support import bench

LOFO = bench.load_script(bench.BENCHMARKS / "paper" / "confidence_lofo.py")
ROOT = Path("/data")
REAL = {"middlebury_2014q": ["ArtL", "Piano", "PianoL", "Recycle", "Playtable", "PlaytableP"],
        "middlebury_2005_2006": ["Books", "Aloe", "Midd1"], "middlebury_2003": ["Cones"],
        "hololens_000": [None], "fountain_p11": [None]}
GROUPS = [["Piano", "PianoL"], ["Playtable", "PlaytableP"]]


def _entries() -> list[SceneEntry]:
    entries = []
    for folder, scenes in REAL.items():
        for scene in scenes:
            path = ROOT / folder / scene if scene else ROOT / folder
            engine = {"max_image_size": 768} if folder == "fountain_p11" else {}
            entries.append(SceneEntry(path.name, path, None, engine))
    entries += [SceneEntry(f"synth_{s:05d}", None, s, {}) for s in (0, 1, 1000)]
    return entries


def _check(folds: dict, entries: list[SceneEntry], families: dict[str, str], groups) -> None:
    names = {e.name for e in entries}
    assert set(folds) == set(families.values())
    for family, fold in folds.items():
        train, val, test = ({e.name for e in getattr(fold, s)} for s in ("train", "validation", "test"))
        assert test == {n for n in names if families[n] == family}  # all of the family is scored
        assert not {families[n] for n in train | val} & {family}  # and none of it trains or picks the checkpoint
        assert not train & val and val and train | val | test == names
        for group in groups:  # variants never straddle two splits
            assert sum(bool(set(group) & split) for split in (train, val, test)) <= 1


def test_families_and_folds_keep_each_family_and_its_variants_out_of_its_own_training():
    entries = _entries()
    families = {e.name: LOFO.family_of(e, ROOT) for e in entries}
    assert families["hololens_000"] == "hololens" and families["fountain_p11"] == "fountain_p11"
    assert families["PianoL"] == "middlebury_2014q" and families["Cones"] == "middlebury_2003"
    assert families["synth_01000"] == "synthetic"
    folds = LOFO.make_folds(entries, families, ["Recycle", "Aloe", "Midd1"], GROUPS)
    assert list(folds) == list(LOFO.FAMILY_ORDER)
    _check(folds, entries, families, GROUPS)
    names = {f: {s: [e.name for e in getattr(fold, s)] for s in ("train", "validation")} for f, fold in folds.items()}
    assert names["middlebury_2014q"]["validation"] == ["Aloe", "Midd1"]
    assert names["middlebury_2005_2006"]["validation"] == ["Recycle"]
    assert names["hololens"]["validation"] == ["Recycle", "Aloe", "Midd1"]
    assert "fountain_p11" in names["hololens"]["train"] and "synth_01000" in names["hololens"]["train"]
    assert not any(n.startswith("synth") for n in names["synthetic"]["train"])


def test_a_validation_variant_takes_its_group_along_and_the_fallback_fills_an_empty_validation():
    entries = _entries()
    families = {e.name: LOFO.family_of(e, ROOT) for e in entries}
    folds = LOFO.make_folds(entries, families, ["Piano"], GROUPS, fallback=("Piano", "Books"))
    assert [e.name for e in folds["hololens"].validation] == ["Piano", "PianoL"]
    assert [e.name for e in folds["middlebury_2014q"].validation] == ["Books"]  # Piano is held out: the fallback
    _check(folds, entries, families, GROUPS)
    with pytest.raises(ValueError, match="different families"):
        LOFO.make_folds(entries, families, ["Aloe"], [["Piano", "Books"]])


@pytest.mark.skipif(not (bench.SHARED_DATA / "middlebury_2014q").is_dir(), reason="needs ../shared/data")
def test_the_recipe_folds():
    from engine.training.recipe import load_recipe

    recipe = load_recipe(bench.REPO_ROOT / LOFO.RECIPE, bench.SHARED_DATA)
    folds = LOFO.recipe_folds(recipe, [1000, 1001, 1002, 1003])
    entries = next(iter(folds.values()))
    entries = [*entries.train, *entries.validation, *entries.test]
    families = {e.name: LOFO.family_of(e, recipe.data_root) for e in entries}
    assert sorted(set(families.values())) == sorted(LOFO.FAMILY_ORDER)
    assert len(entries) == 21 + 10 + 4  # every recipe scene and the held-out synthetic seeds, once
    _check(folds, entries, families, GROUPS)
    fountain = folds["fountain_p11"].test[0]
    assert fountain.engine["max_image_size"] == 768 and fountain.engine["num_source_views"] == 5
