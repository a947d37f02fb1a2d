"""Options dataclasses and their one mapping onto command-line flags."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pytest

from engine.confidence.options import ConfidenceOptions
from engine.consistency import CounterOptions
from engine.core.errors import OptionsError
from engine.core.options import SOURCES, Options, describe, option
from engine.evaluation import EvaluationOptions
from engine.fusion import FusionOptions
from engine.patchmatch import PatchMatchOptions
from engine.refinement.options import RefinementOptions
from engine.refinement.sky import SkyOptions
from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions
from engine.synthetic.layout import RandomSceneKnobs
from workbench.flags.assignments import section_overrides
from workbench.flags.options import add_options_flags, options_from_args
from workbench.rerun.options import StreamOptions

BASELINES = Path(__file__).resolve().parent / "baselines"


def test_defaults_validate_and_round_trip_through_json():
    options = SceneOptions().validate()
    again = SceneOptions.from_dict(json.loads(json.dumps(options.to_dict())))
    assert again == options
    changed = options.replace(depth_range=(0.5, 9.0))
    assert SceneOptions.from_dict(json.loads(json.dumps(changed.to_dict()))).depth_range == (0.5, 9.0)


@pytest.mark.parametrize("change,name", [
    ({"max_image_size": -1}, "max_image_size"),
    ({"num_source_views": 0}, "num_source_views"),
    ({"num_source_views": 33}, "num_source_views"),
    ({"depth_range": (5.0, 1.0)}, "depth_range"),
    ({"depth_range": (0.0, 1.0)}, "depth_range"),
    ({"min_triangulation_angle": float("nan")}, "min_triangulation_angle"),
])
def test_invalid_values_name_the_option(change, name):
    with pytest.raises(OptionsError, match=name):
        SceneOptions(**change).validate()


def test_unknown_keys_are_rejected():
    with pytest.raises(OptionsError, match="unknown option"):
        SceneOptions.from_dict({"max_image_sise": 3})


def test_flags_map_onto_fields_and_keep_defaults_when_absent():
    parser = argparse.ArgumentParser()
    added = add_options_flags(parser, SceneOptions)
    assert "max_image_size" in added and "cache_dir" not in added  # cli=False fields stay off
    args = parser.parse_args(["--max-image-size", "640", "--depth-range", "0.5,20", "--no-undistort"])
    options = options_from_args(SceneOptions, args)
    assert options.max_image_size == 640 and options.depth_range == (0.5, 20.0) and options.undistort is False
    assert options.num_source_views == SceneOptions().num_source_views
    with pytest.raises(SystemExit):
        parser.parse_args(["--depth-range", "1"])


# ---- declared constraints, one-line help, sources -------------------------------------------------------------

def _all_options_classes() -> list[type]:
    """Every Options subclass of engine/ and workbench/ (importing the modules that declare them)."""
    import importlib

    for module in ("engine.run.pipeline", "engine.filtering", "engine.refinement.sky", "engine.synthetic.layout",
                   "workbench.rerun.stream"):
        importlib.import_module(module)
    found, todo = [], list(Options.__subclasses__())
    while todo:
        cls = todo.pop()
        found.append(cls)
        todo.extend(cls.__subclasses__())
    return sorted({c for c in found if c.__module__.startswith(("engine.", "workbench."))}, key=lambda c: c.__name__)


ALL_CLASSES = _all_options_classes()


def test_every_stage_is_found():
    names = {c.__name__ for c in ALL_CLASSES}
    assert {"PatchMatchOptions", "CounterOptions", "ConfidenceOptions", "TrainOptions", "RefinementOptions",
            "SkyOptions", "SceneOptions", "PipelineOptions", "FusionOptions", "EvaluationOptions",
            "RandomSceneKnobs", "RenderSettings", "SparseSettings", "StreamOptions"} <= names


@pytest.mark.parametrize("cls", ALL_CLASSES, ids=lambda c: c.__name__)
def test_every_field_has_one_line_of_help_and_a_source(cls):
    for f in dataclasses.fields(cls):
        line = describe(f)
        assert f.metadata.get("help") and "\n" not in line and len(line) <= 120, (f.name, line)
        assert "SPEC" not in line, (f.name, line)
        nested = f.default_factory is not dataclasses.MISSING and isinstance(f.default_factory(), Options)
        if not nested:  # a nested stage's own fields carry the sources
            assert f.metadata.get("source") in SOURCES, f.name


@pytest.mark.parametrize("cls", ALL_CLASSES, ids=lambda c: c.__name__)
def test_defaults_meet_their_declared_constraints(cls):
    cls().validate()


@pytest.mark.parametrize("cls,change,message", [
    (PatchMatchOptions, {"window": 4}, "option window=4: must be odd and >= 3"),
    (PatchMatchOptions, {"fine_window": 4}, "option fine_window=4: must be 0 (off) or odd and >= 3"),
    (PatchMatchOptions, {"levels": 9}, "option levels=9: must be an integer in 1..8"),
    (PatchMatchOptions, {"iterations": 2.5}, "option iterations=2.5: must be an integer >= 1"),
    (PatchMatchOptions, {"schedule": "fast"}, "option schedule='fast': must be one of paper, acmm"),
    (PatchMatchOptions, {"fine_crease_angle": 90.0}, "option fine_crease_angle=90.0: must be in [0, 90)"),
    (PatchMatchOptions, {"eps_min": 0.0}, "option eps_min=0.0: must be in (0, 1]"),
    (PatchMatchOptions, {"alpha": float("nan")}, "option alpha=nan: must be a finite number"),
    (ConfidenceOptions, {"tau": 1.5}, "option tau=1.5: must be in [0, 1]"),
    (ConfidenceOptions, {"tile": 200}, "option tile=200: must be a multiple of 16 and >= 64"),
    (RefinementOptions, {"lr": (1e-2, 0.0, 1e-3, 1e-4)}, "option lr=(0.01, 0.0, 0.001, 0.0001): every entry must "
                                                         "be > 0"),
    (RefinementOptions, {"keep_confident": -0.1}, "option keep_confident=-0.1: must be in [0, 1]"),
    (SceneOptions, {"depth_range": (5.0, 1.0)}, "option depth_range=(5.0, 1.0): every entry must be > 0; entries "
                                                "increasing"),
    (SceneOptions, {"depth_range": (1.0,)}, "option depth_range=(1.0,): needs 2 values"),
    (RandomSceneKnobs, {"n_views": (5, 3)}, "option n_views=(5, 3): every entry must be >= 2; entries in "
                                            "non-decreasing order"),
    (RandomSceneKnobs, {"texture_kinds": ()}, "option texture_kinds=(): every entry must be one of"),
    (RandomSceneKnobs, {"texture_kinds": ("marble",)}, "option texture_kinds=('marble',): every entry must be one"),
    (EvaluationOptions, {"tolerances": (0.01, float("inf"))}, "must be a finite number"),
    (StreamOptions, {"view": -1}, "option view=-1: must be an integer >= 0"),
])
def test_a_violated_declaration_names_the_option_and_the_rule(cls, change, message):
    with pytest.raises(OptionsError) as info:
        cls(**change).validate()
    assert message in str(info.value)


@pytest.mark.parametrize("cls,change", [
    (PatchMatchOptions, {"fine_window": 0}),  # the 'off' value passes whatever the other constraints say
    (PatchMatchOptions, {"iterations": None}),  # unset optional fields are not checked
    (CounterOptions, {"rel_depth": None}),
    (RefinementOptions, {"keep_confident": None, "confidence_threshold": 0.5}),
    (SceneOptions, {"depth_range": (0.5, 9.0)}),
    (RandomSceneKnobs, {"n_views": (4, 4), "texture_kinds": ("noise",)}),
])
def test_values_within_the_declarations_pass(cls, change):
    cls(**change).validate()


@pytest.mark.parametrize("cls,change,name", [
    (PatchMatchOptions, {"window": 5, "window_step": 3}, "window_step"),
    (PatchMatchOptions, {"k_viewsel": 8, "k_update": 4}, "k_update"),
    (PatchMatchOptions, {"prior_in": 0.1, "prior_out": 0.9}, "prior_in/prior_out"),
    (ConfidenceOptions, {"tile": 64, "overlap": 32}, "overlap"),
    (RefinementOptions, {"scales": 3}, "iters"),
    (RefinementOptions, {"window": 3, "degree": 9}, "degree"),
    (FusionOptions, {"min_num_pixels": 5, "max_num_pixels": 4}, "max_num_pixels"),
])
def test_rules_across_fields_are_still_checked(cls, change, name):
    with pytest.raises(OptionsError, match=f"option {name}="):
        cls(**change).validate()


def test_declarations_are_checked_when_a_class_is_defined():
    with pytest.raises(ValueError, match="source"):
        option(1, "a count")
    with pytest.raises(ValueError, match="source"):
        option(1, "a count", source="folklore")
    with pytest.raises(ValueError, match="one line"):
        option(1, "a count\nwith a story", source="ours")


def test_help_is_generated_with_unit_and_source():
    window = {f.name: f for f in dataclasses.fields(PatchMatchOptions)}["window"]
    assert describe(window) == "matching window side (odd) [px] (default from: ACMM)"
    parser = argparse.ArgumentParser()
    add_options_flags(parser, PatchMatchOptions)
    text = " ".join(parser.format_help().split())
    assert "matching window side (odd) [px] (default: 11, from: ACMM)" in text
    for cls in ALL_CLASSES:  # every generated help formats (argparse chokes on a stray %)
        parser = argparse.ArgumentParser()
        add_options_flags(parser, cls)
        parser.format_help()


def test_renamed_options_still_load_under_their_former_names():
    assert RefinementOptions.from_dict({"refined_conf_tau": 0.3}).refined_confidence_tau == 0.3
    assert RefinementOptions.field_name("refined_conf_tau") == "refined_confidence_tau"
    assert RefinementOptions.field_name("nonsense") is None
    assert SkyOptions.from_dict({"conf_tau": 0.2}).unreliable_below == 0.2
    assert section_overrides(["refinement.refined_conf_tau=0.2"], "refinement", RefinementOptions) == {
        "refined_confidence_tau": 0.2}
    with pytest.raises(OptionsError, match="given twice"):
        RefinementOptions.from_dict({"refined_conf_tau": 0.3, "refined_confidence_tau": 0.2})


def test_a_saved_run_with_a_former_option_name_opens_with_its_value(fake_run, tmp_path):
    """metrics.json of a full run made before refined_conf_tau was renamed: the pipeline's options, the fusion rule,
    the viewer and the summary read its value."""
    import json
    import shutil

    from engine.run.fused_maps import FusionRule
    from workbench.viewer.session import ViewerSession

    run = tmp_path / "run"
    shutil.copytree(fake_run, run)
    metrics = json.loads((run / "metrics.json").read_text())
    saved = PipelineOptions(pipeline="full").to_dict()
    refinement = saved["refinement"]
    refinement["refined_conf_tau"] = 0.3
    del refinement["refined_confidence_tau"]
    metrics["options"] = {"scene": metrics.get("options", {}).get("scene", {}), **saved}
    metrics["pipeline"] = "full"
    (run / "metrics.json").write_text(json.dumps(metrics))
    assert PipelineOptions.from_dict(saved, saved=True).refinement.refined_confidence_tau == 0.3
    rule = FusionRule.from_saved(metrics["options"], "full")
    assert (rule.fused_confidence_tau, rule.threshold_option) == (0.3, "refinement.refined_confidence_tau")
    assert ViewerSession.open(run).run_rule("full").fused_confidence_tau == 0.3


def test_the_documented_confidence_flag_still_works():
    assert section_overrides(["confidence.tau=0.3"], "confidence", ConfidenceOptions) == {"tau": 0.3}


@pytest.mark.parametrize("path", sorted(BASELINES.glob("*/*.json")), ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_saved_regression_baselines_load_without_loss(path):
    saved = json.loads(path.read_text())["metrics"]["options"]
    scene = SceneOptions.from_dict(saved["scene"])
    rest = {k: v for k, v in saved.items() if k != "scene"}
    options = PipelineOptions.from_dict(rest)
    # under today's names: a renamed option (refinement.refined_conf_tau, ...) keeps its value
    assert {"scene": scene.to_dict(), **options.to_dict()} == {"scene": saved["scene"],
                                                               **PipelineOptions.current_names(rest)}


def test_a_run_saved_before_an_option_existed_is_re_run_as_it_was_made():
    """A probe or region re-run of a run saved before the active set and convergence-driven pass ends existed must
    not switch them on (``from_dict(saved=True)``), while a new configuration takes today's defaults."""
    old = PipelineOptions().to_dict()
    for key in ("active_share", "converge_ratio"):
        del old["patchmatch"][key]
    again = PipelineOptions.from_dict(old, saved=True).patchmatch
    assert (again.active_share, again.converge_ratio) == (-1.0, 0.0)
    fresh = PipelineOptions.from_dict(old).patchmatch
    assert (fresh.active_share, fresh.converge_ratio) == (PatchMatchOptions().active_share,
                                                         PatchMatchOptions().converge_ratio)
    # a saved value always wins, and a run saved with every key loads exactly
    assert PipelineOptions.from_dict(PipelineOptions().to_dict(), saved=True) == PipelineOptions()
