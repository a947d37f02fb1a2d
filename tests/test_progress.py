"""The terminal progress bars time whole passes: from the pass's start to its last view."""

from __future__ import annotations

import re

from workbench.cli.progress import PassProgress


def test_pass_bars_time_each_pass_from_start_to_last_view(monkeypatch, capsys) -> None:
    clock = [1000.0]
    monkeypatch.setattr("tqdm.std.time", lambda: clock[0])
    progress = PassProgress()
    for description in ("level 1 photometric", "level 1 geometric", "level 1 geometric"):
        progress(description, 0, 2)
        for done in (1, 2):
            clock[0] += 30.0  # each view takes 30 s
            progress(description, done, 2)
        clock[0] += 50.0  # work between passes belongs to no bar
    err = capsys.readouterr().err
    # a closed bar leaves one line (carriage returns between its redraws): its last drawing is what stays
    finals = [re.findall(r"(level 1 \w+) *: 100%.*? 2/2 \[(\d\d:\d\d)[\],<]", line)[-1]
              for line in err.split("\n") if line.strip()]
    # one closed bar per pass (the second geometric pass gets its own), each 60 s: both views, nothing after
    assert [f[0] for f in finals] == ["level 1 photometric", "level 1 geometric", "level 1 geometric"], err
    assert {f[1] for f in finals} == {"01:00"}, finals


def test_disabled_progress_prints_nothing(capsys) -> None:
    progress = PassProgress(enabled=False)
    progress("level 0 photometric", 0, 3)
    progress("level 0 photometric", 3, 3)
    assert capsys.readouterr().err == ""
