"""Memory estimate of `deepc run`: grows with the work, names a size that fits, refuses before writing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, SAMPLES

from engine.core.heap_trim import release_free_memory
from engine.patchmatch import PatchMatchOptions
from engine.run.memory import available_memory, current_rss, estimate_run_memory, largest_fitting_size
from engine.run.pipeline import PipelineOptions
from engine.scene import SceneOptions, load_scene


@pytest.fixture(scope="module")
def fountain():
    return load_scene(SAMPLES / "fountain_p11")


def test_estimate_grows_with_image_size_and_source_views(fountain):
    options = PipelineOptions()
    estimates = [estimate_run_memory(fountain, options, size, baseline=0, available=None) for size in (128, 256, 384)]
    assert estimates[0].peak < estimates[1].peak < estimates[2].peak
    sizes = [e.patchmatch for e in estimates]  # per-pixel terms grow with the area (5:3); fusion's chunks saturate
    assert sizes[2] - sizes[1] > 1.4 * (sizes[1] - sizes[0])
    few = load_scene(SAMPLES / "fountain_p11", SceneOptions(num_source_views=2))
    assert estimate_run_memory(few, options, baseline=0).patchmatch < estimate_run_memory(
        fountain, options, baseline=0).patchmatch


def test_largest_fitting_size_fits_and_the_next_does_not(fountain):
    options = PipelineOptions(patchmatch=PatchMatchOptions(iterations=1))
    full = estimate_run_memory(fountain, options, baseline=100 << 20, available=None)
    full.available = (100 << 20) + (full.peak - (100 << 20)) * 2 // 3  # less than the full size needs
    assert not full.fits
    size = largest_fitting_size(fountain, options, full)
    assert size is not None and 64 <= size < 384
    assert estimate_run_memory(fountain, options, size, baseline=full.baseline).peak <= full.available
    assert estimate_run_memory(fountain, options, size + 32, baseline=full.baseline).peak > full.available


def test_system_readings_are_plausible():
    assert 10 << 20 < current_rss() < 64 << 30
    free = available_memory()
    assert free is None or free > 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_freed_heap_memory_goes_back_to_the_system():
    # freeing a 20 MiB mmap'ed block raises glibc's mmap threshold past 2 MiB: the blocks below come from the
    # heap, and every other one freed leaves holes that stay resident until trimmed (engine/core/heap_trim.py)
    import numpy as np

    big = np.ones(20 << 20, np.uint8)
    del big
    blocks = [np.ones(2 << 20, np.uint8) for _ in range(40)]
    del blocks[::2]
    held = current_rss()
    assert release_free_memory()
    assert current_rss() < held - (30 << 20)


def test_run_refuses_before_writing_anything_when_memory_is_short(tmp_path):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "workbench.cli", "run", str(SAMPLES / "tiny"), "--out", str(out),
                             "--headless", "--max-memory", "64"], capture_output=True, text=True, cwd=REPO,
                            timeout=300)
    errors = [line for line in result.stderr.splitlines() if line.startswith("deepc: error:")]
    assert result.returncode == 2 and len(errors) == 1 and "Traceback" not in result.stderr
    assert "not enough memory" in errors[0] and "--ignore-memory-check" in errors[0]
    assert "memory: estimated peak" in result.stderr
    assert not out.exists()


def _rss_file_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("RssFile:"):
            return int(line.split()[1]) / 1024
    return float("nan")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
def test_a_file_read_through_a_map_leaves_the_resident_set(tmp_path) -> None:
    """Counting a cloud's points per view reads its records through a map; the pages it read do not stay resident
    (on fountain_p11 768 they were 144 MiB at the end of a run)."""
    from engine.core.heap_trim import release_mapped_pages
    from engine.run.view_shares import points_per_view

    records = np.zeros(8_000_000, [("x", "<f4"), ("source_view", "<i4")])  # 64 MB, like a fused cloud's records
    records["source_view"] = np.arange(len(records)) % 7
    path = tmp_path / "records.bin"
    records.tofile(path)
    del records
    mapped = np.memmap(path, [("x", "<f4"), ("source_view", "<i4")], mode="r")
    before = _rss_file_mb()
    counts = points_per_view(mapped["source_view"], 7)
    assert counts.tolist() == [len(mapped) // 7 + (1 if k < len(mapped) % 7 else 0) for k in range(7)]
    assert _rss_file_mb() - before < 32  # at most a chunk's pages resident, not the file's 61 MiB
    np.asarray(mapped["source_view"]).sum()  # read all of it through the map
    assert _rss_file_mb() - before > 48
    assert release_mapped_pages(mapped["source_view"])
    assert _rss_file_mb() - before < 8


def test_patchmatch_runs_without_the_colour_images_cached(tmp_path, monkeypatch):
    """The run's colour images (12 bytes a pixel) are not held while PatchMatch runs (its grey images are made
    before); fusion reads them again, so the cloud keeps its colours."""
    from engine.run import pipeline

    scene = load_scene(SAMPLES / "tiny")
    cached_during_patchmatch = []
    run_patchmatch = pipeline.run_patchmatch

    def spy(*args, **kwargs):
        cached_during_patchmatch.append(scene._image.cache_info().currsize)
        return run_patchmatch(*args, **kwargs)

    monkeypatch.setattr(pipeline, "run_patchmatch", spy)
    options = PipelineOptions(patchmatch=PatchMatchOptions(iterations=1, levels=1, geom_passes=0))
    result = pipeline.run_pipeline(scene, tmp_path, options)
    assert cached_during_patchmatch == [0]
    assert len(result.cloud) and np.asarray(result.cloud.rgb).any()
