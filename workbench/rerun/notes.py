"""What a recording holds and lacks, as text documents beside its maps (``about``, ``missing/<view>/<kind>``).

``deepc replay`` writes them into a notes recording with the recording's id (the viewer merges the two); a run
that records logs them into its own recording from what it is going to log. The layouts (``layouts/``) show
``missing/<view>/<kind>`` in place of a map the recording lacks.
"""

from __future__ import annotations

from layouts import MAP_LABELS, PIPELINES, Contents, view_title
from workbench.rerun.legends import legend_markdown

# why a map may be absent, per kind (shown in the text panel that replaces it)
MISSING_REASONS = {
    "depth": "no PatchMatch iterations of this view were recorded (the run was thinned to another view with "
             "--set stream.view=N, or the file holds an exported state only)",
    "normal": "no PatchMatch iterations of this view were recorded",
    "cost": "no PatchMatch iterations of this view were recorded",
    "selected_count": "no PatchMatch iterations of this view were recorded",
    "error": "no GT depth for this view: the error against GT needs the scene's GT depth maps",
    "counter": "the counter is computed once PatchMatch has finished: the run stopped before, or this view was "
               "not recorded",
    "confidence": "only the fast and full pipelines run the confidence network (this run did not, or stopped "
                  "before it)",
    "label": "GT labels need GT depth for this view and the confidence stage (fast/full pipeline); recordings "
             "made before labels were logged have none",
    "refined_depth": "refined depth maps are not part of run recordings",
}


def about_markdown(contents: Contents, view: str, layout: str, live: bool = False) -> str:
    """Markdown: how to scrub, the views, the maps each holds and lacks, the fused clouds."""
    lines = [f"# {layout} layout · {view_title(view)}", ""]
    if live:
        lines += ["What this run records (the maps arrive as the run goes).", ""]
    else:
        lines += ["A recording, opened paused at its start: press play or drag the time line. The *latency* rerun "
                  "may show at the top counts from when the run logged each message, not a delay of this replay.",
                  ""]
    if contents.timeline == "view_iteration":
        lines.append("Scrub **view_iteration** to watch one view converge (every view's n-th iteration sits at n); "
                     "**pass** jumps pass by pass over all levels, coarse to fine; **iteration** is the engine's "
                     "global step, all views interleaved. `deepc replay FILE --view NAME` shows another view.")
    else:
        lines.append("Recorded before per-view timelines: **iteration** is the engine's global step with all views "
                     "interleaved, so a view's maps change only every few steps.")
    lines += ["", f"**Views** ({len(contents.views)}): " + ", ".join(view_title(v) for v in contents.views), ""]
    for v in contents.views:
        have = [MAP_LABELS.get(k, k) for k in MAP_LABELS if contents.has(f"/maps/{v}/{k}")]
        lacks = [MAP_LABELS.get(k, k) for k in MAP_LABELS
                 if k != "refined_depth" and not contents.has(f"/maps/{v}/{k}")]
        lines.append(f"- {view_title(v)}: " + (", ".join(have) or "no maps")
                     + (f"; **lacks** {', '.join(lacks)}" if lacks else ""))
    clouds = [p for p in PIPELINES if contents.has(f"/world/fused/{p}")]
    lines += ["", "**Fused clouds**: " + (", ".join(clouds) if clouds else "none (no fusion stage recorded)")]
    return "\n".join(lines) + "\n"


def log_notes(rec, contents: Contents, view: str, layout: str, legend: bool = False, live: bool = False) -> None:
    """Log ``about``, a ``missing/<view>/<kind>`` document per map ``contents`` lacks, ``missing/fused`` and
    (``legend``) the colour legend, all static, into the recording stream ``rec``."""
    import rerun as rr  # lazy: rerun

    markdown = rr.MediaType.MARKDOWN
    rec.log("about", rr.TextDocument(about_markdown(contents, view, layout, live), media_type=markdown), static=True)
    if legend:
        rec.log("legend", rr.TextDocument(legend_markdown(), media_type=markdown), static=True)
    for v in contents.views or [view]:
        for kind, reason in MISSING_REASONS.items():
            if not contents.has(f"/maps/{v}/{kind}"):
                text = f"**{MAP_LABELS.get(kind, kind)} · {view_title(v)}** is not in this recording: {reason}."
                rec.log(f"missing/{v}/{kind}", rr.TextDocument(text, media_type=markdown), static=True)
    rec.log("missing/fused", rr.TextDocument("No fused cloud in this recording: the run stopped before fusion.",
                                             media_type=markdown), static=True)
