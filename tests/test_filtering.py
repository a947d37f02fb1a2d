"""Confidence and counter (mask-k) filters (Kuhn et al. 2020, §4.1)."""

from __future__ import annotations

import numpy as np
import pytest

from engine.core.errors import OptionsError
from engine.filtering import filter_by_confidence, filter_by_counter


def _maps(seed=0, h=6, w=7):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(1, 5, (h, w)).astype(np.float32)
    depth[0, 0] = 0
    normal = rng.normal(size=(h, w, 3)).astype(np.float32)
    return depth, normal


def test_confidence_keeps_c_at_least_tau():
    depth, normal = _maps()
    conf = np.full(depth.shape, 0.5, np.float32)
    conf[1, 1] = 0.049
    conf[1, 2] = 0.05  # equal to tau: kept
    conf[1, 3] = np.nan  # no confidence: rejected
    d0, n0 = depth.copy(), normal.copy()
    d, n = filter_by_confidence(depth, normal, conf, 0.05)
    assert d[1, 1] == 0 and not n[1, 1].any()
    assert d[1, 2] == depth[1, 2] and np.array_equal(n[1, 2], normal[1, 2])
    assert d[1, 3] == 0
    assert d.dtype == np.float32 and n.dtype == np.float32
    np.testing.assert_array_equal(depth, d0)  # inputs untouched
    np.testing.assert_array_equal(normal, n0)
    assert (d > 0).sum() == (depth > 0).sum() - 2


def test_counter_keeps_k_at_least():
    depth, normal = _maps(1)
    counter = np.arange(depth.size, dtype=np.float32).reshape(depth.shape) % 4
    for k in (0, 1, 2, 3):
        d, n = filter_by_counter(depth, normal, counter, k)
        expect = (counter >= k) & (depth > 0)
        np.testing.assert_array_equal(d > 0, expect)
        assert not n[~(counter >= k)].any()
    d, _ = filter_by_counter(depth, normal, counter.astype(np.uint8), 2)  # integer counters too
    np.testing.assert_array_equal(d > 0, (counter >= 2) & (depth > 0))


def test_bad_inputs():
    depth, normal = _maps()
    with pytest.raises(OptionsError):
        filter_by_confidence(depth, normal, np.ones_like(depth), 1.5)
    with pytest.raises(OptionsError):
        filter_by_counter(depth, normal, np.ones_like(depth), -1)
    with pytest.raises(ValueError):
        filter_by_confidence(depth, normal, np.ones((2, 2)), 0.1)
    with pytest.raises(ValueError):
        filter_by_counter(depth, normal[..., :2], np.ones_like(depth), 1)
    with pytest.raises(OptionsError):
        filter_by_confidence(depth, normal, np.ones_like(depth), float("nan"))
