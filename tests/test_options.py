"""Options dataclasses and their one mapping onto command-line flags."""

from __future__ import annotations

import argparse
import json

import pytest

from engine.errors import OptionsError
from engine.scene import SceneOptions
from workbench.flags import add_options_flags, options_from_args


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
