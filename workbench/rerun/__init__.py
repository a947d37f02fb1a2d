"""Everything sent to rerun: the live per-iteration stream (``stream``, its ``options`` and ``legends``), counter
maps and confidence in the stream (``confidence``), ``.rrd`` recordings and their notes (``recording``,
``notes``, ``run_recording``), probe traces (``probe``) and ``deepc replay`` (``replay``). Blueprints live in the
top-level ``layouts`` package."""
