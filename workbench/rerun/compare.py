"""``deepc replay A.rrd --compare B.rrd``: two recordings side by side, view by view.

The rerun viewer keeps recordings with different recording ids apart (one shown at a time), so the two are
merged into one new recording: every chunk of A is re-logged under ``/a`` and every chunk of B under ``/b``
(``Chunk.with_entity_path`` on each file's chunk stream, read with ``rerun.chunk.RrdReader`` as
:func:`workbench.rerun.replay.recording_contents` reads it; row ids, timelines and components are kept, so both
runs' iterations stay on the one ``view_iteration`` timeline). The ``compare`` layout (``layouts``) then puts each
map of A beside B's, a tab per view (:func:`workbench.rerun.replay.compare_files` writes both files).
"""

from __future__ import annotations

import uuid
from pathlib import Path

SIDES = ("a", "b")
_PROPERTIES = "/__properties"  # a recording's own properties: the merged recording has its own


def merge_recordings(path_a: str | Path, path_b: str | Path, target: str | Path, application_id: str,
                     recording_id: str | None = None) -> Path:
    """Write one recording at ``target`` holding every entity of ``path_a`` under ``/a`` and of ``path_b``
    under ``/b``; returns ``target``."""
    from rerun.chunk import LazyChunkStream, RrdReader  # lazy: rerun

    def prefixed(path: str | Path, side: str):
        def move(chunk):
            path = chunk.entity_path
            return [] if path.startswith(_PROPERTIES) else [chunk.with_entity_path(f"/{side}{path}")]

        return RrdReader(str(path)).stream().flat_map(move)

    streams = [prefixed(p, side) for p, side in zip((path_a, path_b), SIDES, strict=True)]
    LazyChunkStream.merge(*streams).write_rrd(str(target), application_id=application_id,
                                              recording_id=recording_id or f"compare-{uuid.uuid4()}")
    return Path(target)
