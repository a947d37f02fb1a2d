"""Depth resampling never invents depths between surfaces."""

from __future__ import annotations

import numpy as np

from engine.core.resample import resample_depth


def test_integer_downsampling_takes_an_existing_valid_depth():
    depth = np.zeros((8, 8), np.float32)
    depth[:, :5] = 2.0
    depth[:, 5:] = 9.0
    depth[0, 0] = 0.0
    out = resample_depth(depth, (2, 2))
    assert out.shape == (2, 2)
    assert set(np.unique(out)) <= {0.0, 2.0, 9.0}
    assert out[0, 0] == 2.0 and out[0, 1] == 9.0  # right block: 4 of 16 at 2 m, 12 at 9 m


def test_mostly_invalid_blocks_become_invalid():
    depth = np.zeros((4, 4), np.float32)
    depth[0, 0] = 3.0
    assert resample_depth(depth, (1, 1))[0, 0] == 0.0
    depth[:2, :] = 3.0
    assert resample_depth(depth, (1, 1))[0, 0] == 3.0


def test_other_factors_use_the_nearest_pixel_centre():
    depth = np.arange(12, dtype=np.float32).reshape(3, 4) + 1
    up = resample_depth(depth, (8, 6))
    np.testing.assert_array_equal(up[::2, ::2], depth)
    odd = resample_depth(depth, (3, 2))
    assert set(np.unique(odd)) <= set(np.unique(depth))
