"""The probe's kept pass-start states (engine/run/probe_states.py) and tracing from them over the pixels a traced
pixel depends on (engine/patchmatch/probe/partial.py): the same traces as a whole replay, entry for entry."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.patchmatch.multiscale import replay_view
from engine.patchmatch.probe.partial import dependency_box, pattern_reach, schedule_cone, trace_from_states
from engine.patchmatch.probe.pixel_probe import PixelProbe
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.run.probe import forget_replays, probe_run
from engine.run.probe_states import PARTS_DIR, STATES_DIR, RunStates, StateStore, ViewStates
from engine.scene import load_scene
from support.pm_synthetic import make_scene

REPO = Path(__file__).resolve().parent.parent
# the default schedule's passes (ended by convergence, active set, fine window at level 0, detail restorer) with
# two levels and one geometric pass, ended sooner (converge_ratio) so that a pass's dependency box is smaller than
# the level
OPTS = PatchMatchOptions(levels=2, geom_passes=1, converge_ratio=0.3)
PIXELS = [(0, 0), (127, 95), (63, 47), (3, 80), (120, 2)]


def _dump(traces: list[dict]) -> str:
    return json.dumps(traces, sort_keys=True)


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """A 128x96 synthetic scene, its history, and view 1 replayed whole with the probe on, its pass-start states
    and iterations kept."""
    views, _ = make_scene(128, 96, n_views=3)
    history = PassHistory(tmp_path_factory.mktemp("probe_states") / HISTORY_DIR)
    run_patchmatch(views, OPTS, history=history)
    states: dict = {}
    iterations: dict = {}

    def on_pass(level, pass_index, phase, st, images, cameras):
        states[(level, pass_index if phase == "start" else "end")] = (st.depth.copy(), st.normal.copy())

    def on_iter(event):
        iterations[(event.level, event.pass_index)] = event.iteration + 1

    probe = PixelProbe(1, PIXELS)
    replay_view(views, 1, history.load_snapshot, OPTS, probe=probe, on_pass=on_pass, on_iter=on_iter)
    return views, history, states, iterations, probe.traces()


def test_traces_from_states_equal_the_whole_replay(replayed):
    views, history, states, iterations, full = replayed
    assert any(n < OPTS.pass_iterations(p) for (_, p), n in iterations.items()), "no pass converged early"
    probe = PixelProbe(1, PIXELS)
    trace_from_states(views, 1, states, iterations, history.load_snapshot, OPTS, probe)
    assert _dump(probe.traces()) == _dump(full)
    # each pixel alone (its own, smaller box; a corner's leaves most of level 0 out) gives the same trace
    for i in (0, 1, 3):
        probe = PixelProbe(1, [PIXELS[i]])
        trace_from_states(views, 1, states, iterations, history.load_snapshot, OPTS, probe)
        assert _dump(probe.traces()) == _dump([full[i]]), PIXELS[i]


def test_the_box_is_smaller_than_the_level(replayed):
    """The equalities above are not the whole level replayed: a corner pixel's box leaves pixels out at level 0
    in every pass (and those passes run into the active set's iterations)."""
    _, _, _, iterations, _ = replayed
    reach = pattern_reach(OPTS)
    assert reach == 13
    assert min(iterations[(0, p)] for p in range(2)) > 2
    for p in range(2):
        x0, y0, x1, y1 = dependency_box([(0, 0)], 2 * iterations[(0, p)], reach, 128, 96)
        assert (x1 - x0) * (y1 - y0) < 128 * 96, iterations
    assert dependency_box([(0, 0)], 2, 13, 96, 72) == (0, 0, 27, 27)
    assert dependency_box([(50, 40), (60, 30)], 1, 13, 96, 72) == (37, 17, 74, 54)


def test_schedule_cone_of_the_default_schedule_covers_fountain_768():
    """From scratch the cone covers the view: the first pixel of a view needs a whole replay (module doc)."""
    cone = schedule_cone(PatchMatchOptions(), 768, 512, 3)
    assert cone[0]["share"] == 1.0 and cone[1]["share"] == 1.0
    acmm = schedule_cone(PatchMatchOptions(schedule="acmm"), 768, 512, 3)
    assert acmm[0]["radius"] == 2 * 7 * 13 and acmm[0]["share"] < 0.5 and acmm[1]["share"] == 1.0


def test_store_round_trip_staleness_and_lru(tmp_path):
    rng = np.random.default_rng(0)
    states = {(1, 0): (rng.random((6, 8), dtype=np.float32), rng.random((6, 8, 3), dtype=np.float32)),
              (1, "end"): (rng.random((6, 8), dtype=np.float32), rng.random((6, 8, 3), dtype=np.float32))}
    store = StateStore(tmp_path / "states")
    store.save(0, "k1", ViewStates(states, {(1, 0): 3}))
    got = store.load(0, "k1")
    assert got is not None and got.iterations == {(1, 0): 3} and set(got.states) == set(states)
    for k, (z, n) in states.items():
        assert np.array_equal(got.states[k][0], z) and np.array_equal(got.states[k][1], n)
    assert store.load(0, "k2") is None and store.load(1, "k1") is None  # stale key, missing view
    (tmp_path / "states" / "view3.npz").write_bytes(b"garbage")
    assert store.load(3, "k1") is None
    # least recently used goes first: view 0 is read after view 1 was written
    size = store.path(0).stat().st_size
    small = StateStore(tmp_path / "states", cap_bytes=2 * size + 100)
    small.save(1, "k1", ViewStates(states, {}))
    os.utime(store.path(0), ns=(1, 1))
    os.utime(small.path(1), ns=(2, 2))
    assert small.load(0, "k1") is not None  # refreshes view 0
    small.save(2, "k1", ViewStates(states, {}))
    assert not small.path(1).exists() and small.path(0).exists() and small.path(2).exists()
    assert small.size_bytes() <= small.cap_bytes
    assert not list((tmp_path / "states").glob("*.tmp*"))


TINY = REPO / "sample_scenes" / "tiny"


def test_the_run_keeps_every_views_states_so_a_first_probe_replays_no_view_whole(tmp_path, monkeypatch):
    """deepc run with its history records each view's pass-start states as PatchMatch makes them: the first
    probe of a view, in a fresh process, traces from them (no whole replay) and gives the whole replay's JSON."""
    import engine.run.probe as probe_module

    out = tmp_path / "run"
    options = PipelineOptions(patchmatch=PatchMatchOptions(levels=2, geom_passes=1, converge_ratio=0.3))
    run_pipeline(load_scene(TINY), out, options, history=PassHistory(out / HISTORY_DIR))
    states = out / HISTORY_DIR / STATES_DIR
    assert sorted(p.name for p in states.glob("view*.npz")) == [f"view{i}.npz" for i in range(5)]
    assert not (states / PARTS_DIR).exists()
    forget_replays()
    whole_replays = []
    replay = probe_module.replay_view
    monkeypatch.setattr(probe_module, "replay_view", lambda *a, **k: whole_replays.append(a) or replay(*a, **k))
    first = probe_run(out, 2, [(100, 80), (3, 117)])
    assert whole_replays == []
    assert _dump(first) == _dump(probe_run(out, 2, [(100, 80), (3, 117)], stored_states=False))
    assert len(whole_replays) == 1


def test_views_whose_states_would_pass_the_cap_are_not_recorded(tmp_path):
    views, _ = make_scene(128, 96, n_views=3)
    history = PassHistory(tmp_path / HISTORY_DIR)
    history.states = RunStates(StateStore(tmp_path / HISTORY_DIR / STATES_DIR, cap_bytes=600_000))
    run_patchmatch(views, OPTS, history=history)  # a view's states: 0.52 MB by the estimate (0.7 x 16 B)
    assert history.states.recording == {0}
    stored = history.states.finish(lambda i: f"key{i}")
    assert stored == [0] and history.states.store.load(0, "key0") is not None
    assert not (tmp_path / HISTORY_DIR / STATES_DIR / PARTS_DIR).exists()


def test_probe_run_from_kept_states_equals_a_whole_replay(tmp_path):
    """probe_run: a probe of a view of a run made without states replays it whole and keeps its states on disk;
    another pixel, in a fresh process's memory, is traced from them, with the same JSON as a whole replay of it."""
    out = tmp_path / "run"
    options = PipelineOptions(patchmatch=PatchMatchOptions(levels=2, geom_passes=1))
    run_pipeline(load_scene(TINY), out, options, history=PassHistory(out / HISTORY_DIR))
    for p in (out / HISTORY_DIR / STATES_DIR).glob("view*.npz"):
        p.unlink()  # as a run made before the run recorded them
    probe_run(out, 1, [(10, 12)])
    assert (out / HISTORY_DIR / STATES_DIR / "view1.npz").is_file()
    forget_replays()  # as a new process: only the disk store
    from_states = probe_run(out, 1, [(100, 80), (159, 0)])
    whole = probe_run(out, 1, [(100, 80), (159, 0)], stored_states=False)
    assert _dump(from_states) == _dump(whole)
