"""``--set STAGE.NAME=VALUE``: every options dataclass of the pipeline reachable and listed, one typed parser."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import types

import pytest
from conftest import SAMPLES

from engine.core.errors import OptionsError
from engine.core.options import Options
from engine.patchmatch import PatchMatchOptions
from engine.run.folder import refinement_key
from engine.run.pipeline import PipelineOptions
from workbench.cli.main import build_parser
from workbench.cli.probe import region_overrides
from workbench.flags.assignments import nested_options, section_overrides
from workbench.flags.run_options import run_options_from_args, run_sections


def deepc(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def leaf_fields(prefix: str, options: Options) -> list[tuple[str, dataclasses.Field]]:
    """('stage.name', field) of every field of ``options``, nested options walked down."""
    out = []
    for f in dataclasses.fields(options):
        value = getattr(options, f.name)
        out += leaf_fields(f"{prefix}.{f.name}", value) if isinstance(value, Options) else [(f"{prefix}.{f.name}", f)]
    return out


def run_options(*set_items: str, pipeline: str = "vanilla"):
    args = build_parser().parse_args(["run", str(SAMPLES / "tiny"), "--out", "unused", "--pipeline", pipeline,
                                      *[a for item in set_items for a in ("--set", item)]])
    return run_options_from_args(args)


def test_every_options_dataclass_of_the_pipeline_is_a_stage():
    stages = nested_options(PipelineOptions)
    assert stages and set(stages) <= set(run_sections())
    assert all(issubclass(cls, Options) for cls in stages.values())


def test_help_options_lists_every_option_of_every_stage():
    result = deepc("run", "--help-options")
    assert result.returncode == 0, result.stderr
    lines = {line.split()[0]: line for line in result.stdout.splitlines()[1:]}
    expected = [row for name in nested_options(PipelineOptions)
                for row in leaf_fields(name, getattr(PipelineOptions(), name))]
    assert len(expected) > 100  # the walk found the stages' fields
    for key, f in expected:
        assert key in lines, f"{key} missing from deepc run --help-options"
        line = lines[key]
        assert f.metadata["help"] in line
        assert f.metadata["source"] in line
        if f.metadata.get("unit"):
            assert f.metadata["unit"] in line
    # the other stages of deepc run too (scene, mesh, stream), and nothing else
    listed = {key for name, defaults in run_sections().items() for key, _ in leaf_fields(name, defaults)}
    assert set(lines) == listed


def test_counter_evaluation_and_sky_options_reach_the_runs_options():
    scene, options, _ = run_options("counter.cap=7", "evaluation.voxel_size=0.02", "evaluation.tolerances=0.01,0.1",
                                    "refinement.sky.far_factor=2", "refinement.sky_filter=off", "scene.cache_dir=/x")
    assert options.counter.cap == 7 and options.evaluation.voxel_size == 0.02
    assert options.evaluation.tolerances == (0.01, 0.1)
    assert options.refinement.sky.far_factor == 2.0 and not options.refinement.sky_filter
    assert scene.cache_dir == "/x"
    # what metrics.json records, and what a re-run reads back from it
    saved = json.loads(json.dumps(options.to_dict()))
    assert saved["counter"]["cap"] == 7 and saved["refinement"]["sky"]["far_factor"] == 2.0
    assert PipelineOptions.from_dict(saved, saved=True) == options


def test_a_run_records_and_uses_the_counter_and_evaluation_options(tmp_path):
    out = tmp_path / "out"
    result = deepc("run", SAMPLES / "tiny", "--out", out, "--headless", "--levels", "1", "--iterations", "1",
                   "--geom-passes", "1", "--no-history", "--set", "counter.cap=7",
                   "--set", "evaluation.tolerances=0.02,0.1")
    assert result.returncode == 0, result.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["options"]["counter"]["cap"] == 7 and metrics["options"]["evaluation"]["tolerances"] == [0.02, 0.1]
    assert metrics["eval"]["tolerances"] == [0.02, 0.1]


def test_set_items_of_one_stage_merge_and_win_over_flags():
    _, options, _ = run_options("patchmatch.iterations=2", "refinement.sky.far_factor=2",
                                "refinement.sky.max_texture_std=0.1")
    assert options.patchmatch.iterations == 2
    assert (options.refinement.sky.far_factor, options.refinement.sky.max_texture_std) == (2.0, 0.1)
    args = build_parser().parse_args(["run", "s", "--out", "o", "--iterations", "3",
                                      "--set", "patchmatch.iterations=4"])
    assert run_options_from_args(args)[1].patchmatch.iterations == 4


def test_defaults_are_unchanged_by_the_plumbing():
    scene, options, stream = run_options()
    assert options == PipelineOptions() and scene == type(scene)() and stream == type(stream)()


def test_a_run_saved_before_the_sky_options_reads_as_it_was_made():
    old = PipelineOptions().to_dict()
    del old["refinement"]["sky"]
    assert PipelineOptions.from_dict(old, saved=True) == PipelineOptions()


def test_the_sky_options_do_not_change_the_refined_maps_key():
    scene = types.SimpleNamespace(root=str(SAMPLES / "tiny"), options=types.SimpleNamespace(to_dict=dict))
    changed = PipelineOptions().replace(refinement=PipelineOptions().refinement.replace(
        sky=PipelineOptions().refinement.sky.replace(far_factor=3.0)))
    assert refinement_key(scene, "w", changed, "i") == refinement_key(scene, "w", PipelineOptions(), "i")


@pytest.mark.parametrize("item,fragment", [
    ("nonsense.x=1", "unknown stage 'nonsense'"),
    ("counter.nonsense=1", "no option 'nonsense'"),
    ("counter.cap=x", "not a valid int"),
    ("evaluation.tolerances=a,b", "not numbers"),
    ("counter.check_facing=maybe", "not a valid bool"),
    ("refinement.sky=1", "group of options"),
    ("refinement.scales.x=1", "no options of its own"),
    ("counter.cap", "expected STAGE.NAME=VALUE"),
    ("counter.cap=0", "cap"),
])
def test_a_bad_set_item_is_one_line_and_exit_2(tmp_path, item, fragment):
    result = deepc("run", SAMPLES / "tiny", "--out", tmp_path / "o", "--headless", "--set", item)
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("deepc: error: ") and fragment in lines[0], result.stderr
    assert not (tmp_path / "o").exists()


def test_probe_set_goes_through_the_typed_parser():
    assert region_overrides(["window=7", "patchmatch.tau0=0.7", "plane_propagation=off", "iterations=none"]) == \
        {"window": 7, "tau0": 0.7, "plane_propagation": False, "iterations": None}
    assert region_overrides(["window=7"]) == section_overrides(["patchmatch.window=7"], "patchmatch",
                                                               PatchMatchOptions)
    with pytest.raises(OptionsError, match="not a valid int"):
        region_overrides(["window=7.5"])
    with pytest.raises(OptionsError, match="unknown stage 'confidence'"):
        region_overrides(["confidence.tau=0.1"])
    with pytest.raises(OptionsError, match="no option 'nonsense'"):
        region_overrides(["nonsense=1"])
    with pytest.raises(OptionsError, match="expected NAME=VALUE"):
        region_overrides(["window"])


def test_probe_set_errors_are_one_line_before_the_run_is_read(tmp_path):
    result = deepc("probe", tmp_path, "--view", "0", "--region", "0,0,8,8", "--set", "window=x")
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "'window=x'" in lines[0] and "not a valid int" in lines[0], result.stderr
