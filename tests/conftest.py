"""Shared fixtures: paths to the shipped sample scenes and to ../shared/data (optional)."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import pytest

from engine.run.distributed import LocalExecutor
from support.fake_run import make_fake_run  # noqa: F401  (tests import it from here)

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "sample_scenes"
SHARED_DATA = REPO.parent / "shared" / "data"


def sample_scene_dirs() -> list[Path]:
    return sorted(p for p in SAMPLES.iterdir() if (p / "sparse").is_dir())


def shared_scene_dirs() -> list[Path]:
    if not SHARED_DATA.is_dir():
        return []
    return sorted(p for p in SHARED_DATA.iterdir() if (p / "sparse").is_dir())


@pytest.fixture
def temple_copy(tmp_path: Path) -> Path:
    """A writable copy of the shipped Middlebury temple scene (text model, no GT)."""
    dst = tmp_path / "temple"
    shutil.copytree(SAMPLES / "middlebury_temple", dst)
    return dst


@pytest.fixture
def fountain_copy(tmp_path: Path) -> Path:
    """A writable copy of the shipped fountain_p11 scene (binary model, GT depth and points)."""
    dst = tmp_path / "fountain"
    shutil.copytree(SAMPLES / "fountain_p11", dst, ignore=shutil.ignore_patterns("points.ply"))
    return dst


def make_noisy_run(scene_dir: Path, out_dir: Path) -> Path:
    """A vanilla run folder made from GT depth with wrong depths in random blobs (outliers) and a counter map
    that only partly tells them apart, so that a confidence network has something to learn."""
    import numpy as np

    from engine.run.folder import write_map, write_metrics
    from engine.scene import load_scene
    from support.gt_normals import depth_normals

    scene = load_scene(scene_dir)
    rng = np.random.default_rng(0)
    for v in scene.views:
        gt = scene.gt_depth(v.index)
        h, w = gt.shape
        yy, xx = np.mgrid[:h, :w]
        bad = np.zeros((h, w), bool)
        for _ in range(6):
            cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(6, 16)
            bad |= (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
        depth = np.where(bad, gt * rng.uniform(0.7, 0.9), gt).astype(np.float32)
        normal = depth_normals(v.camera, gt)
        depth[~normal.any(axis=2)] = 0
        counter = np.where(bad, rng.integers(0, 3, (h, w)), rng.integers(1, 5, (h, w))) * (depth > 0)
        write_map(out_dir, "depth", v.name, depth)
        write_map(out_dir, "normal", v.name, normal)
        write_map(out_dir, "counter", v.name, counter.astype(np.float32))
    write_metrics(out_dir, {"scene": scene.name, "scene_path": str(Path(scene_dir).resolve()), "pipeline": "vanilla",
                            "num_images": len(scene.views), "options": {"scene": scene.options.to_dict()}})
    return out_dir


@pytest.fixture(scope="session")
def fake_run(tmp_path_factory) -> Path:
    """A fake `deepc run` output of sample_scenes/tiny (vanilla + fast maps)."""
    return make_fake_run(SAMPLES / "tiny", tmp_path_factory.mktemp("fake_run"))


@pytest.fixture(scope="session")
def browser_context():
    """Debian chromium driven by playwright; requests leaving 127.0.0.1 are blocked."""
    from support.browser import CHROMIUM, chromium

    if not CHROMIUM.exists():
        pytest.skip("needs /usr/bin/chromium (scripts/setup.sh --test installs it)")
    with chromium() as context:
        yield context


@contextlib.contextmanager
def running_viewer(run_dir: Path):
    """A ViewerApp on a free port for ``run_dir``, idle (first exact cloud shown); always stopped."""
    from workbench.viewer.app import ViewerApp
    from workbench.viewer.session import ViewerSession

    viewer = ViewerApp(ViewerSession.open(run_dir), port=0)
    try:
        assert viewer.wait_idle(120)
        yield viewer
    finally:
        viewer.stop()


def open_page(context, app):
    """A browser page on ``app``'s viewer, once the server sees its client and the page says Connected."""
    page = context.new_page()
    page.goto(f"http://127.0.0.1:{app.port}/")
    wait_for(lambda: len(app.server.get_clients()) > 0)
    page.get_by_text("Connected").wait_for()
    return page


def wait_for(predicate, timeout: float = 30.0, interval: float = 0.05):
    """Poll ``predicate`` until it is truthy; fail the test after ``timeout`` seconds."""
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    pytest.fail(f"timed out after {timeout} s waiting for {getattr(predicate, '__name__', 'a condition')}")


def run_async(coro, timeout: float = 300.0):
    """Run ``coro`` to completion on a fresh event loop in its own thread: playwright's sync API (the
    browser tests) leaves an event loop running on the main thread, where ``asyncio.run`` refuses to start."""
    import asyncio
    import concurrent.futures

    with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
        return pool.submit(asyncio.run, coro).result(timeout=timeout)


@pytest.fixture(scope="module")
def noisy_run(tmp_path_factory):
    """A tiny vanilla run with noisy maps (make_noisy_run), one per test module."""
    return make_noisy_run(SAMPLES / "tiny", tmp_path_factory.mktemp("noisy_run"))


@pytest.fixture
def inspector_app(noisy_run):
    """A viewer on ``noisy_run`` whose inspector probes and re-runs with hand-made traces (``support.probe_traces``);
    ``inspector_app.hand`` records the calls. Stopped afterwards."""
    from support.probe_traces import HandProbe
    from workbench.viewer.app import ViewerApp
    from workbench.viewer.session import ViewerSession

    viewer = ViewerApp(ViewerSession.open(noisy_run), port=0)
    hand = HandProbe(viewer.session.scene, noisy_run)
    viewer.inspector.probe_fn, viewer.inspector.region_fn = hand.probe, hand.rerun
    viewer.hand = hand
    try:
        assert viewer.wait_idle(120)
        yield viewer
    finally:
        viewer.stop()


class RecordingExecutor(LocalExecutor):
    """Tasks in this process (``LocalExecutor``), keeping every job it ran in ``jobs``."""

    def __init__(self):
        super().__init__()
        self.jobs = []

    def map(self, fn, jobs, on_result=None):
        self.jobs.extend(jobs)
        return super().map(fn, jobs, on_result)
