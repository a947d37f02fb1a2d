"""The pixel probe (engine/patchmatch/probe/pixel_probe.py, explain.py), the pass history and the probe on finished runs
(engine/run/pass_history.py, engine/run/probe.py, engine/run/probe_output.py) and their command line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from engine.core.errors import DeepCError
from engine.io.packing import pack_float32, unpack_float32
from engine.patchmatch import PatchMatchOptions, run_patchmatch
from engine.patchmatch.multiscale import replay_view
from engine.patchmatch.probe.pixel_probe import MAX_PROBE_PIXELS, PixelProbe, level_pixel
from engine.run.folder import read_map
from engine.run.pass_history import HISTORY_DIR, PassHistory
from engine.run.pipeline import PipelineOptions, run_pipeline
from engine.run.probe import probe_run, rerun_region
from engine.run.probe_output import probe_path
from engine.scene import load_scene
from support.pm_synthetic import make_scene

REPO = Path(__file__).resolve().parent.parent
# every kind of pass: photometric at the coarsest level (random start), photometric with the detail restorer,
# geometric; min_improvement applies before a pass's last iteration
OPTS = PatchMatchOptions(iterations=2, levels=2, geom_passes=1)
PIXELS = [(0, 0), (10, 10), (33, 20), (63, 47), (31, 24)]
ENTRY_KEYS = {"level", "pass", "iteration", "colour", "x_level", "y_level", "before", "after", "candidates", "winner",
              "decided_by", "source_views"}
CANDIDATE_KEYS = {"origin", "depth", "normal", "cost", "view_costs", "selected_views", "view_weights"}


@pytest.fixture(scope="module")
def small_scene():
    return make_scene(64, 48, n_views=3)


@pytest.fixture(scope="module")
def probed(small_scene):
    views, _ = small_scene
    probe = PixelProbe(1, PIXELS)
    return run_patchmatch(views, OPTS), run_patchmatch(views, OPTS, probe=probe), probe


def test_probe_leaves_the_maps_unchanged(probed):
    plain, with_probe, _ = probed
    for a, b in zip(plain, with_probe, strict=True):
        for name in ("depth", "normal", "cost", "selected_views"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_traces_follow_the_kernel_to_the_written_maps(probed):
    """Every half-step of every pixel: the explainer's winner is what the kernel stored, and the last entry's
    after is the final map."""
    _, maps, probe = probed
    traces = probe.traces()
    assert [(t["x"], t["y"]) for t in traces] == PIXELS
    n_entries = 2 * (1 + OPTS.geom_passes) * OPTS.iterations  # levels x passes x iterations, one colour each
    decided = set()
    for t in traces:
        assert t["view"] == "view1" and t["source_views"] == ["view0", "view2"]
        its = t["iterations"]
        assert len(its) == n_entries
        assert [(e["level"], e["pass"], e["iteration"]) for e in its] == sorted(
            ((e["level"], e["pass"], e["iteration"]) for e in its), key=lambda k: (-k[0], k[1], k[2]))
        for e in its:
            assert ENTRY_KEYS <= set(e)
            assert e["explained"], (t["x"], t["y"], e["level"], e["pass"], e["iteration"])
            assert (e["x_level"] + e["y_level"]) % 2 == e["colour"]
            assert all(CANDIDATE_KEYS <= set(c) for c in e["candidates"])
            assert e["candidates"][0]["origin"] in ("current", "upsampled")
            assert 0 <= e["winner"] < len(e["candidates"])
            if e["decided_by"] in ("min_improvement", "detail_restorer"):
                assert e["winner"] == 0 and e["after"]["depth"] == e["before"]["depth"]
            decided.add(e["decided_by"])
            if e["level"] == 0:
                assert (e["x_level"], e["y_level"]) == (t["x"], t["y"])
        assert its[-1]["after"]["depth"] == float(maps[1].depth[t["y"], t["x"]])
        assert t["final"]["depth"] == its[-1]["after"]["depth"]
    origins = {c["origin"].split(":")[0] for t in traces for e in t["iterations"] for c in e["candidates"]}
    assert {"current", "upsampled", "pattern", "perturbation", "random"} <= origins
    assert {"cost", "detail_restorer"} <= decided
    json.dumps(traces, allow_nan=False)  # plain JSON


@pytest.mark.parametrize("changes", [{"pattern": "acmm", "combos": "all8"},
                                     {"view_sampling": "deterministic", "plane_propagation": False},
                                     {"detail_restorer_reference": "upsampled", "pattern": "deepc_far",
                                      "k_update": 8, "k_viewsel": 4}],
                         ids=["acmm_all8", "deterministic_raw_depth", "upsampled_far"])
def test_explainer_follows_other_settings(small_scene, changes):
    views, _ = small_scene
    opts = OPTS.replace(**changes)
    probe = PixelProbe(0, PIXELS[:3])
    maps = run_patchmatch(views, opts, probe=probe)
    for t in probe.traces():
        assert all(e["explained"] for e in t["iterations"])
        assert t["iterations"][-1]["after"]["depth"] == float(maps[0].depth[t["y"], t["x"]])
        if changes.get("combos") == "all8":
            assert sum(c.get("refinement") is not None for c in t["iterations"][0]["candidates"]) <= 8


def test_probe_marks_the_pixels_the_active_set_skips(small_scene):
    """With the active set on, a skipped pixel's entry says so and keeps its hypothesis; every entry still
    follows the kernel."""
    views, _ = small_scene
    opts = PatchMatchOptions(iterations=6, levels=1, geom_passes=0, active_share=0.0)
    block = [(x, y) for y in range(20, 28) for x in range(28, 36)]
    probe = PixelProbe(1, block)
    maps = run_patchmatch(views, opts, probe=probe)
    skipped = 0
    for t in probe.traces():
        for e in t["iterations"]:
            assert e["explained"], (t["x"], t["y"], e["iteration"])
            if e["skipped"]:
                skipped += 1
                assert e["decided_by"] == "active_set" and e["iteration"] >= 2 and e["after"] == e["before"]
        assert t["iterations"][-1]["after"]["depth"] == float(maps[1].depth[t["y"], t["x"]])
    assert skipped > 0


def test_level_pixel_maps_centres():
    assert level_pixel(0, 0, 64, 48, 32, 24) == (0, 0)
    assert level_pixel(63, 47, 64, 48, 32, 24) == (31, 23)
    assert level_pixel(33, 20, 64, 48, 32, 24) == (16, 10)
    assert level_pixel(10, 5, 100, 100, 100, 100) == (10, 5)


def test_bad_probes_are_one_line_errors(small_scene):
    views, _ = small_scene
    with pytest.raises(DeepCError, match="at most 64"):
        PixelProbe(0, [(i, 0) for i in range(MAX_PROBE_PIXELS + 1)])
    with pytest.raises(DeepCError, match="view index"):
        PixelProbe(-1, [(0, 0)])
    with pytest.raises(DeepCError, match="two integers"):
        PixelProbe(0, [(1.5, 2)])
    with pytest.raises(DeepCError, match="no pixel"):
        PixelProbe(0, [])
    with pytest.raises(DeepCError, match=r"pixel \(64, 0\) is outside view view0 \(64x48"):
        run_patchmatch(views, OPTS, probe=PixelProbe(0, [(64, 0)]))
    with pytest.raises(DeepCError, match="view 7 does not exist"):
        run_patchmatch(views, OPTS, probe=PixelProbe(7, [(1, 1)]))


def test_pack_depth_is_lossless():
    rng = np.random.default_rng(0)
    depth = rng.uniform(1, 9, (37, 53)).astype(np.float32)
    depth[::3] = 0.0
    depth[0, :4] = [np.float32(1e-30), np.float32(3.4e38), -0.0, np.float32(2.5)]
    packed, shape = pack_float32(depth)
    assert np.array_equal(unpack_float32(packed, shape).view(np.uint32), depth.view(np.uint32))


def test_replay_of_one_view_gives_the_runs_maps(small_scene, tmp_path):
    views, _ = small_scene
    history = PassHistory(tmp_path / HISTORY_DIR)
    maps = run_patchmatch(views, OPTS, history=history)
    assert history.passes == [(1, 1), (0, 1)]
    reader = PassHistory(tmp_path / HISTORY_DIR)
    reader.open(views, OPTS.validate(), 2, [(1, 1), (0, 1)])
    for i in range(len(views)):
        m = replay_view(views, i, reader.load_snapshot, OPTS)
        assert np.array_equal(m.depth, maps[i].depth) and np.array_equal(m.normal, maps[i].normal)
        assert np.array_equal(m.cost, maps[i].cost)
    with pytest.raises(DeepCError, match="other inputs"):
        reader.open(views, OPTS.replace(seed=3), 2, [])


# ---------------------------------------------------------------------------------------------- finished runs

TINY = REPO / "sample_scenes" / "tiny"
RUN_OPTS = PipelineOptions(patchmatch=PatchMatchOptions(iterations=1, levels=2, geom_passes=1))


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("probe_run")
    scene = load_scene(TINY)
    probe = PixelProbe(1, [(10, 12), (100, 80)])
    run_pipeline(scene, out, RUN_OPTS, probe=probe, history=PassHistory(out / HISTORY_DIR))
    return out, scene, probe


def test_run_writes_traces_with_final_entries(tiny_run):
    from engine.confidence.data import view_labels

    out, scene, probe = tiny_run
    name = scene.views[1].name
    depth = read_map(out, "depth", name)
    labels = view_labels(scene, 1, depth)  # the whole view's: the probe labels its pixels alone
    for x, y in probe.pixels:
        data = json.loads(probe_path(out, name, x, y).read_text())
        assert data["view"] == name and (data["x"], data["y"]) == (x, y)
        assert data["iterations"][-1]["after"]["depth"] == float(depth[y, x])
        final = data["final"]
        assert final["gt_depth"] is not None and final["label"] == int(labels[y, x])
        assert final["error"] == pytest.approx(abs(final["depth"] - final["gt_depth"]) / final["gt_depth"])
        verdicts = final["counter_verdicts"]
        assert set(verdicts) == {scene.views[j].name for j in scene.views[1].source_views}
        assert sum(v == "consistent" for v in verdicts.values()) == final["counter"]
        assert final["counter"] == int(read_map(out, "counter", name)[y, x])


def test_probe_on_demand_equals_the_runs_probe(tiny_run):
    out, scene, probe = tiny_run
    name = scene.views[1].name
    traces = probe_run(out, name, probe.pixels)
    assert json.dumps(traces, sort_keys=True) == json.dumps(probe.traces(), sort_keys=True)
    assert probe_run(out, 1, [(5, 5)])[0]["view"] == name
    with pytest.raises(DeepCError, match="outside view"):
        probe_run(out, name, [(160, 5)])
    with pytest.raises(DeepCError, match="no view named"):
        probe_run(out, "nope.png", [(1, 1)])
    with pytest.raises(DeepCError, match="view 9 does not exist"):
        probe_run(out, 9, [(1, 1)])


def test_region_rerun(tiny_run):
    out, scene, _ = tiny_run
    box = (40, 30, 24, 20)
    r = rerun_region(out, 1, box)
    assert r.box == box and r.depth_before.shape == r.depth_after.shape == (20, 24)
    assert np.array_equal(r.depth_before, read_map(out, "depth", scene.views[1].name)[30:50, 40:64])
    assert r.error_before.shape == (20, 24) and 0 <= r.within_1pct_after <= 100
    # same options: the crop (own random streams) lands close to the run's maps
    assert abs(r.within_1pct_after - r.within_1pct_before) < 15
    r = rerun_region(out, scene.views[1].name, box, level=1, pass_index=1, overrides={"window": 7},
                     probe_pixels=[(50, 40)])
    (trace,) = r.traces
    assert [(e["level"], e["pass"]) for e in trace["iterations"]] == [(1, 1), (0, 0), (0, 1)]
    assert all(e["explained"] and (e["x_level"] + e["y_level"]) % 2 == e["colour"] for e in trace["iterations"])
    assert trace["iterations"][-1]["after"]["depth"] == float(r.depth_after[40 - 30, 50 - 40])
    assert (trace["iterations"][0]["x_level"], trace["iterations"][0]["y_level"]) == level_pixel(50, 40, 160, 120,
                                                                                                   80, 60)
    for kwargs, message in [({"overrides": {"levels": 1}}, "cannot change"), ({"overrides": {"nope": 1}}, "unknown"),
                            ({"level": 2}, "level 2 does not exist"), ({"pass_index": 3}, "pass 3 does not exist"),
                            ({"probe_pixels": [(0, 0)]}, "outside the box")]:
        with pytest.raises(DeepCError, match=message):
            rerun_region(out, 1, box, **kwargs)
    with pytest.raises(DeepCError, match="not inside view"):
        rerun_region(out, 1, (150, 0, 20, 10))


def test_run_without_history_says_so(tiny_run, tmp_path):
    out, _, _ = tiny_run
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / HISTORY_DIR)
    with pytest.raises(DeepCError, match="no pass history"):
        probe_run(copy, 0, [(1, 1)])


def _deepc(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "workbench.cli", *args], capture_output=True, text=True,
                          timeout=600, cwd=REPO)


def test_cli_probe_errors_are_one_line_and_exit_2(tiny_run, tmp_path):
    out, _, _ = tiny_run
    for args, message in [(("probe", str(out), "--view", "9", "--pixel", "1,1"), "view 9 does not exist"),
                          (("probe", str(out), "--view", "0", "--pixel", "1;1"), "not a pixel"),
                          (("probe", str(out), "--view", "0", "--pixel", "500,1"), "outside view"),
                          (("run", str(TINY), "--out", str(tmp_path / "o"), "--headless", "--probe",
                            "view_000.png:5,500"), "outside view"),
                          (("run", str(TINY), "--out", str(tmp_path / "o"), "--headless", "--probe", "7"),
                           "expected VIEW:X,Y")]:
        res = _deepc(*args)
        assert res.returncode == 2, res.stderr
        lines = [ln for ln in res.stderr.splitlines() if ln.startswith("deepc: error:")]
        assert len(lines) == 1 and message in lines[0], res.stderr
    assert not (tmp_path / "o" / "metrics.json").exists()


def test_cli_run_with_probe_and_without_history(tmp_path):
    out = tmp_path / "run"
    res = _deepc("run", str(TINY), "--out", str(out), "--headless", "--levels", "1", "--iterations", "1",
                 "--geom-passes", "1", "--probe", "view_001.png:10,12;30,20")
    assert res.returncode == 0, res.stderr
    depth = read_map(out, "depth", "view_001.png")
    for x, y in [(10, 12), (30, 20)]:
        data = json.loads(probe_path(out, "view_001.png", x, y).read_text())
        assert len(data["iterations"]) == 2 and data["iterations"][-1]["after"]["depth"] == float(depth[y, x])
    assert (out / HISTORY_DIR / "manifest.json").is_file()
    res = _deepc("run", str(TINY), "--out", str(tmp_path / "plain"), "--headless", "--levels", "1", "--iterations",
                 "1", "--geom-passes", "1", "--no-history")
    assert res.returncode == 0, res.stderr
    assert not (tmp_path / "plain" / HISTORY_DIR).exists()


def test_cli_probe_writes_traces(tiny_run):
    out, scene, _ = tiny_run
    res = _deepc("probe", str(out), "--view", scene.views[2].name, "--pixel", "7,9")
    assert res.returncode == 0, res.stderr
    assert probe_path(out, scene.views[2].name, 7, 9).is_file()
    res = _deepc("probe", str(out), "--view", "2", "--region", "20,20,16,16", "--set", "window=9")
    assert res.returncode == 0, res.stderr
    assert "within 1%" in res.stdout


def test_cli_run_with_probe_records_the_traces_in_the_run_recording(tmp_path):
    """``deepc run --probe ... --record``: the run's recording holds the traces under probe/<view>/<x>_<y>/."""
    from workbench.rerun.replay import recording_contents

    out, rrd = tmp_path / "run", tmp_path / "run.rrd"
    res = _deepc("run", str(TINY), "--out", str(out), "--headless", "--levels", "1", "--iterations", "1",
                 "--geom-passes", "1", "--probe", "view_001.png:10,12", "--record", str(rrd))
    assert res.returncode == 0, res.stderr
    entities = recording_contents(rrd).contents.entities
    assert "/probe/001_view_001.png/10_12/cost" in entities and "/maps/001_view_001.png/depth" in entities
