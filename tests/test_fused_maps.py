"""What a pipeline fuses has one owner (engine/run/fused_maps.py): a ``full`` run of sample_scenes/tiny made with a
non-default ``refinement.keep_confident`` is shown by the viewer and meshed by ``deepc mesh --method tsdf`` from
exactly the maps the pipeline fused (Kuhn et al. 2020, §4.2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from engine.fusion import write_fused_ply
from engine.refinement.options import RefinementOptions
from workbench.cli.main import main
from workbench.viewer.session import ViewerSession, ViewParams

REPO = Path(__file__).resolve().parent.parent
TINY = REPO / "sample_scenes" / "tiny"
KEEP = 0.5  # refinement.keep_confident: not the default
# a short refinement, as tests/test_refined_runs.py's
CHEAP_FLAGS = ["--set", "refinement.scales=2", "--set", "refinement.fast_iters=60,40", "--set",
               "refinement.iters=10,10", "--set", "refinement.lr=0.01,0.01", "--set", "refinement.lr_slots=1,1"]


def _recording(module, calls: list):
    """``module.mesh_run`` that also records the depth maps it is given (the TSDF's input)."""
    real = module.mesh_run

    def mesh_run(scene, cloud, depths, options):
        calls.append([np.array(d) for d in depths])
        return real(scene, cloud, depths, options)
    return mesh_run


@pytest.fixture(scope="module")
def full_run(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    """A full run of tiny with ``keep_confident`` 0.5 meshed by TSDF as it runs, and the (H, W) depth maps the
    pipeline handed to the TSDF: the maps it fused."""
    import engine.run.pipeline as pipeline

    assert RefinementOptions().keep_confident != KEEP
    out = tmp_path_factory.mktemp("full") / "run"
    calls: list = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(pipeline, "mesh_run", _recording(pipeline, calls))
        assert main(["run", str(TINY), "--out", str(out), "--pipeline", "full", "--schedule", "acmm", "--seed", "0",
                     "--headless", "--no-history", "--mesh", "tsdf", *CHEAP_FLAGS,
                     "--set", f"refinement.keep_confident={KEEP}"]) == 0
    assert json.loads((out / "metrics.json").read_text())["options"]["refinement"]["keep_confident"] == KEEP
    assert len(calls) == 1
    return out, calls[0]


def test_the_viewers_cloud_for_the_runs_own_settings_is_fused_ply(full_run, tmp_path):
    run, fused = full_run
    session = ViewerSession.open(run)
    params = session.run_params()
    assert params.pipeline == "full"
    for (depth, _), want in zip(session.filtered_maps(params), fused, strict=True):
        np.testing.assert_array_equal(depth, want)
    write_fused_ply(tmp_path / "viewer.ply", session.cloud(params))
    assert (tmp_path / "viewer.ply").read_bytes() == (run / "fused.ply").read_bytes()


def test_deepc_mesh_tsdf_integrates_the_maps_the_pipeline_fused(full_run, tmp_path, monkeypatch):
    """``deepc run --mesh tsdf`` meshed the pipeline's own in-memory maps; ``deepc mesh --method tsdf`` reads them
    back from the run folder: the same maps, to the bit."""
    import workbench.cli.mesh as mesh_command

    run, fused = full_run
    copy = tmp_path / "run"  # mesh a copy: the other tests read the original
    for path in run.rglob("*"):
        if path.is_file():
            (copy / path.relative_to(run)).parent.mkdir(parents=True, exist_ok=True)
            (copy / path.relative_to(run)).write_bytes(path.read_bytes())
    calls: list = []
    monkeypatch.setattr(mesh_command, "mesh_run", _recording(mesh_command, calls))
    assert main(["mesh", str(copy), "--method", "tsdf"]) == 0
    assert len(calls) == 1
    for got, want in zip(calls[0], fused, strict=True):
        np.testing.assert_array_equal(got, want)


def test_the_rule_follows_the_run_and_the_viewers_overrides(full_run):
    from engine.run.fused_maps import FusionRule, fused_maps

    run, fused = full_run
    session = ViewerSession.open(run)
    rule = session.run_rule("full")
    saved = json.loads((run / "metrics.json").read_text())["options"]
    assert rule == FusionRule.from_saved(saved, "full")
    assert (rule.keep_confident, rule.fused_confidence_tau, rule.sky_filter, rule.mask_k) == (KEEP, 0.05, True, 0)
    params = session.run_params()
    # the default keep_confident fuses other maps: the run's own value matters here
    default = fused_maps(session.scene, FusionRule.of("full", *_stages(saved)), session.data)
    assert any(not np.array_equal(f.depth, d) for f, d in zip(default, fused, strict=True))
    # the viewer's overrides go through the same rule: a stricter threshold and a counter filter only drop pixels
    stricter = session.filtered_maps(ViewParams(pipeline="full", fused_confidence_tau=0.5, mask_k=2,
                                                fusion=params.fusion))
    kept = sum(int((d > 0).sum()) for d, _ in stricter)
    assert 0 < kept < sum(int((d > 0).sum()) for d in fused)
    assert all(not (d[~(f > 0)] > 0).any() for (d, _), f in zip(stricter, fused, strict=True))


def test_the_summary_names_the_threshold_full_applied(full_run, capsys):
    from engine.run.folder import read_run_metrics
    from workbench.cli.run import print_run_summary

    print_run_summary(read_run_metrics(full_run[0]), str(full_run[0]))
    assert "of the estimates kept at refinement.refined_confidence_tau 0.05" in capsys.readouterr().out


def _stages(saved: dict):
    """The saved confidence and refinement options with refinement.keep_confident back at its default."""
    from engine.confidence.options import ConfidenceOptions

    refinement = RefinementOptions.from_dict(saved["refinement"]).replace(
        keep_confident=RefinementOptions().keep_confident)
    return ConfidenceOptions.from_dict(saved["confidence"]), refinement
