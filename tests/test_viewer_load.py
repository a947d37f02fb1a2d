"""The viewer under load (short version of benchmarks/performance/bench_viewer_load.py): 5 websocket clients sending
50 GUI events per second for 5 s, one dropping and reconnecting: no error, every client ends with the
exact result of the last event, reconnecting and late clients get the current state, memory bounded. Also
that the viser internals the viewer relies on to keep one cloud in flight per client still exist."""

from __future__ import annotations

import pytest
from conftest import running_viewer

from support.viewer_load import load, summarise

pytestmark = pytest.mark.slow


def test_five_clients_fifty_events_per_second(fake_run):
    with running_viewer(fake_run) as app:
        result = load(app, clients=5, rate=50, seconds=5, reconnect_every=2, timeout=300)
    summary = summarise(result)
    assert summary["errors"] == [] and summary["settled"]
    assert summary["events"] >= 200  # the load really was applied
    # every event was followed by an exact result (or its client dropped before one arrived), and every
    # event that can be previewed was answered
    assert summary["exact_measured"] + summary["events_dropped_by_reconnect"] == summary["events"]
    assert summary["preview_measured"] > 0.5 * summary["events"]
    assert summary["final_exact_s_max"] is not None and summary["final_exact_s_max"] < 10
    assert summary["reconnects"] >= 2 and summary["reconnects_current"] == summary["reconnects"]
    assert summary["late_client_current"]
    assert summary["rss_growth_last_vs_first_third"] < 0.5


def test_previews_wait_for_the_previous_cloud_to_leave(fake_run):
    # viser 1.1 internals used by ViewerApp._wait_for_delivery: if they move, previews would pile up again
    with running_viewer(fake_run) as app:
        buffer = app.server._websock_server.get_message_buffer()
        assert isinstance(buffer.generator_cursors, dict) and isinstance(buffer.message_counter, int)
        assert app._cloud_message_id >= 0  # the first exact cloud was pushed and its message id recorded
