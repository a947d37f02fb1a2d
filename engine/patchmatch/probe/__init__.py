"""The pixel probe: what PatchMatch did at a few pixels of one view, half-step by half-step (``pixel_probe``), and
why each hypothesis changed, candidate by candidate (``explain``). docs/probe_schema.md has the trace format."""
