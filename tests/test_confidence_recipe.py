"""Training recipes: what a recipe names is checked before anything runs, and `deepc train --recipe` trains
from the recipe alone (engine runs, sampling, weights, model card with citations), resumably."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from engine.core.errors import DeepCError
from engine.training.recipe import load_recipe

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "sample_scenes"
SHIPPED = REPO / "engine" / "confidence" / "recipes" / "deepc_middle.toml"

BASE = """
[recipe]
name = "unit"
[data]
root = "{root}"
groups = [["tiny", "small"]]
[engine]
schedule = "acmm"
iterations = 1
num_source_views = 2
[split]
train = {train}
validation = {validation}
test = {test}
[training]
epochs = 2
steps_per_epoch = 2
batch = 1
crop = 64
base_width = 4
bf16 = false
"""


def write_recipe(tmp_path: Path, train='["tiny"]', validation="[]", test="[]", extra: str = "") -> Path:
    path = tmp_path / "recipe.toml"
    path.write_text(BASE.format(root=SAMPLES, train=train, validation=validation, test=test) + extra)
    return path


def test_recipe_resolves_scenes_synthetic_seeds_and_per_scene_options(tmp_path):
    path = write_recipe(tmp_path, train='["tiny", "synthetic:3,5-6"]',
                        test='[{ path = "fountain_p11", max_image_size = 192 }, "middlebury_temple"]')
    recipe = load_recipe(path)
    train = recipe.scenes("train")
    assert [e.name for e in train] == ["tiny", "synth_00003", "synth_00005", "synth_00006"]
    assert train[0].path == SAMPLES / "tiny" and train[1].seed == 3 and train[1].path is None
    fountain, temple = recipe.scenes("test")
    assert fountain.engine == {"schedule": "acmm", "iterations": 1, "num_source_views": 2, "max_image_size": 192}
    assert fountain.run_name == "fountain_p11_192px" and temple.run_name == "middlebury_temple"
    assert recipe.options.base_width == 4 and recipe.options.epochs == 2


@pytest.mark.parametrize("train, validation, test, extra, message", [
    ('["nowhere"]', "[]", "[]", "", "scene 'nowhere' not found"),
    ('["middlebury_temple"]', "[]", "[]", "", "'middlebury_temple' has no ground-truth depth"),
    ('["tiny"]', '["middlebury_temple"]', "[]", "", "'middlebury_temple' has no ground-truth depth"),
    ('["tiny"]', '["tiny"]', "[]", "", "tiny is in both the train and the validation split"),
    ('["tiny"]', "[]", '["small"]', "", "variants tiny, small of one scene are split across test, train"),
    ('["tiny", "tiny"]', "[]", "[]", "", "named twice"),
    ('["synthetic:a-b"]', "[]", "[]", "", "seeds must look like"),
    ("[]", "[]", "[]", "", "no training scenes"),
    ('["tiny"]', "[]", "[]", "lr = -1\n", "option lr=-1: must be > 0"),
    ('["tiny"]', "[]", "[]", "widths = 3\n", "widths"),
])
def test_bad_recipes_are_one_line_errors_naming_the_file(tmp_path, train, validation, test, extra, message):
    path = write_recipe(tmp_path, train, validation, test, extra)
    with pytest.raises(DeepCError, match=message) as info:
        load_recipe(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


@pytest.mark.shared_data
def test_shipped_recipe_keeps_fountain_out_of_training_and_variants_together():
    recipe = load_recipe(SHIPPED, REPO.parent / "shared" / "data") if (REPO.parent / "shared" / "data").is_dir() \
        else None
    if recipe is None:
        pytest.skip("../shared/data is not here: the shipped recipe's scenes cannot be resolved")
    names = {split: {e.name for e in recipe.scenes(split)} for split in ("train", "validation", "test")}
    assert "fountain_p11" in names["test"] and "fountain_p11" not in names["train"] | names["validation"]
    assert any(e.synthetic for e in recipe.scenes("train")), "the synthetic generator stays in the mix"
    assert any(not e.synthetic for e in recipe.scenes("train"))


def deepc(*args, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def test_train_command_refuses_a_bad_recipe_and_writes_nothing(tmp_path):
    path = write_recipe(tmp_path, train='["middlebury_temple"]')
    out = tmp_path / "out" / "w.pt"
    result = deepc("train", "--recipe", path, "--out", out, "--cache", tmp_path / "cache")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "ground-truth depth" in lines[0]
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


@pytest.mark.slow
def test_train_command_with_a_recipe_trains_resumes_and_writes_a_card(tmp_path):
    path = write_recipe(tmp_path, train='["tiny"]', validation='["fountain_p11"]',
                        extra="")
    text = path.read_text().replace('validation = ["fountain_p11"]',
                                    'validation = [{ path = "fountain_p11", max_image_size = 96 }]')
    path.write_text(text)
    out, cache = tmp_path / "w" / "unit.pt", tmp_path / "cache"
    first = deepc("train", "--recipe", path, "--data", SAMPLES, "--out", out, "--cache", cache, "--max-epochs", "1")
    assert first.returncode == 0, first.stderr
    assert (cache / "runs" / "tiny" / "metrics.json").is_file()
    assert (cache / "runs" / "fountain_p11_96px" / "metrics.json").is_file()
    assert "recipe unit (vanilla maps): 1 training scenes" in first.stderr
    resumed = deepc("train", "--recipe", path, "--data", SAMPLES, "--out", out, "--cache", cache)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming from" in resumed.stderr and "running the engine" not in resumed.stderr  # runs cached
    summary = json.loads(resumed.stdout.strip().splitlines()[-1])
    assert summary["epochs_done"] == 2
    card = Path(summary["model_card"]).read_text()
    assert "| train | tiny |" in card and "| validation | fountain_p11 |" in card
    assert "Strecha" in card  # fountain_p11's citation, read from its README
    assert "widths [4, 8, 16, 32]" in card and "```toml" in card
    history = json.loads(out.with_name("unit.history.json").read_text())
    assert set(history["best"]["validation"]["sets"]) == {"fountain_p11"}


def test_a_recipe_extends_another_and_overrides_it_key_by_key(tmp_path):
    base = write_recipe(tmp_path, train='["tiny", "synthetic:3"]', test='["middlebury_temple"]')
    child = tmp_path / "child.toml"
    child.write_text('[recipe]\nname = "child"\nextends = "recipe.toml"\n[training]\nepochs = 5\n'
                     '[refined]\nweights = "w.pt"\n')
    recipe, parent = load_recipe(child), load_recipe(base)
    assert recipe.name == "child" and recipe.options.epochs == 5 and recipe.refined == {"weights": "w.pt"}
    assert recipe.options.base_width == parent.options.base_width == 4  # the rest of [training] is the base's
    assert recipe.splits == parent.splits and "(extended)" in recipe.text
    grandchild = tmp_path / "grandchild.toml"
    grandchild.write_text('[recipe]\nextends = "child.toml"\n')
    with pytest.raises(DeepCError, match="one level only"):
        load_recipe(grandchild)
    (tmp_path / "orphan.toml").write_text('[recipe]\nextends = "missing.toml"\n')
    with pytest.raises(DeepCError, match="missing.toml: training recipe not found"):
        load_recipe(tmp_path / "orphan.toml")


@pytest.mark.shared_data
def test_the_two_shipped_networks_share_one_split():
    data = REPO.parent / "shared" / "data"
    if not data.is_dir():
        pytest.skip("../shared/data is not here: the shipped recipes' scenes cannot be resolved")
    first = load_recipe(SHIPPED, data)
    second = load_recipe(SHIPPED.with_name("deepc_refined.toml"), data)
    assert second.splits == first.splits and second.refined is not None and first.refined is None
