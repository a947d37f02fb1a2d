"""The viewer under load (short version of benchmarks/bench_viewer_load.py): 5 websocket clients sending
50 GUI events per second for 5 s, one dropping and reconnecting: no error, every client ends with the
exact result of the last event, reconnecting and late clients get the current state, memory bounded."""

from __future__ import annotations

import sys

import pytest
from conftest import REPO, run_async, running_viewer

sys.path.insert(0, str(REPO / "benchmarks"))

from bench_viewer_load import load, summarise  # noqa: E402

pytestmark = pytest.mark.slow


def test_five_clients_fifty_events_per_second(fake_run):
    with running_viewer(fake_run) as app:
        result = run_async(load(app, clients=5, rate=50, seconds=5, reconnect_every=2), timeout=300)
    summary = summarise(result)
    assert summary["errors"] == [] and summary["settled"]
    assert summary["events"] >= 200  # the load really was applied
    assert summary["updates_measured"] == summary["events"]  # every event was answered by an update
    assert summary["final_exact_s_max"] is not None and summary["final_exact_s_max"] < 10
    assert summary["reconnects"] >= 2 and summary["reconnects_current"] == summary["reconnects"]
    assert summary["late_client_current"]
    assert summary["rss_growth_last_vs_first_third"] < 0.5
