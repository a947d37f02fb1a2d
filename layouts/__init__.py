"""Rerun blueprints, one per debugging task. Change what you see here, not in engine code.

Each layout is a function of a recording's :class:`Contents` (which views and entities it holds, which
timelines) and the view to show, returning an ``rrb.Blueprint``. Panel titles name the view first, short enough
to stay readable in a narrow panel (``003 · depth (m)``; the view's image name is in the tab and ``about``). A
recording opened from a file starts paused at its start; a live stream follows the run. A map the
recording lacks gets a text panel saying so (``missing/<view>/<kind>``, written by ``deepc replay`` next
to the recording) instead of an empty "No data available" panel.

- ``iterations``: PatchMatch iterations of one view — depth, normals, cost, selected views, error
  against GT, counter (and confidence with GT labels when the recording holds confidence, e.g. scored
  while PatchMatch ran), and the per-iteration scalars, with the cameras in 3-D, the colour legends and
  what the recording holds.
- ``pipelines``: the fused clouds of the pipelines side by side with one view's maps.
- ``confidence``: confidence against GT labels, the image and the depth error: one tab per view (the
  chosen view's tab open).
- ``probe``: the probed pixels of a view (``probe/<view>/<x>_<y>``, ``workbench/rerun/probe.py``), one tab
  each: cost and depth against the iteration, the candidates on the pixel's ray in 3-D, the pixel's window in
  each source image, the candidate table and the final estimate, beside the view's depth and error maps.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import rerun.blueprint as rrb

# the maps of a view the layouts show, with their panel labels
# depth carries its unit: rerun's hover prints the depth without one
MAP_LABELS = {"depth": "depth (m)", "normal": "normal", "cost": "cost", "selected_count": "views used",
              "error": "error vs GT", "counter": "counter", "confidence": "confidence", "label": "GT labels",
              "refined_depth": "refined depth (m)"}
# (short: a panel title; the legend and "about this recording" say what each one is)
STATS_LABELS = {"mean_cost": "mean cost", "changed_pct": "changed %", "within_1pct": "in 1 % of GT",
                "confidence_auc": "conf. AUC", "confidence_kept_pct": "conf ≥ τ %", "pixel_scale": "px scale"}
PIPELINES = ("vanilla", "fast", "full")
SCRUB_TIMELINE = "view_iteration"  # one view's iterations (workbench/rerun/stream.py); older recordings: "iteration"


@dataclasses.dataclass
class Contents:
    """What a recording holds: view entity names (``maps/<view>/...``), the entity paths with data (``None``:
    everything the stream logs, e.g. for a run that is about to record) and the timelines."""

    views: list[str]
    entities: set[str] | None = None
    timelines: set[str] = dataclasses.field(default_factory=lambda: {SCRUB_TIMELINE, "pass", "iteration"})
    live: bool = False  # a run streaming now: the viewer follows it (a file opens paused at its start)

    def has(self, path: str) -> bool:
        return self.entities is None or path in self.entities

    @property
    def timeline(self) -> str:
        """The timeline to scrub one view's iterations on."""
        return SCRUB_TIMELINE if SCRUB_TIMELINE in self.timelines or not self.timelines else "iteration"


def view_title(view: str) -> str:
    """Human name of a view entity ``012_img\\/a.png`` -> ``img/a.png (view 12)``."""
    raw = view.replace("\\", "")
    index, _, name = raw.partition("_")
    return f"{name} (view {int(index)})" if index.isdigit() and name else raw


def view_label(view: str) -> str:
    """Short name of a view entity for panel titles: ``012_img\\/a.png`` -> ``012``."""
    index = view.replace("\\", "").partition("_")[0]
    return index if index.isdigit() else view_title(view)


def map_panel(contents: Contents, view: str, kind: str):
    """A 2-D panel of ``maps/<view>/<kind>`` titled with the view, or a text panel saying it is not recorded."""
    label = f"{view_label(view)} · {MAP_LABELS.get(kind, kind)}"
    path = f"/maps/{view}/{kind}"
    if contents.has(path):
        return rrb.Spatial2DView(name=label, origin=path)
    return rrb.TextDocumentView(name=f"{label}: not recorded", origin=f"/missing/{view}/{kind}")


def _text_panels() -> rrb.Tabs:
    # contents: the document at the origin only (legend/<kind> below it are one map's legend each)
    return rrb.Tabs(rrb.TextDocumentView(name="legend", origin="/legend", contents="$origin"),
                    rrb.TextDocumentView(name="about this recording", origin="/about", contents="$origin"))


def _panels(contents: Contents, state: str = "expanded") -> list:
    # a file: paused, no loop (scrub it; playing a loaded file from the start replays the run); live: follow the run
    play = {"play_state": "following"} if contents.live else {"play_state": "paused", "loop_mode": "off"}
    return [rrb.TimePanel(state=state, timeline=contents.timeline, **play),
            rrb.SelectionPanel(state="collapsed"),
            rrb.BlueprintPanel(state="collapsed")]


def iterations(contents: Contents, view: str) -> rrb.Blueprint:
    stats = [rrb.TimeSeriesView(name=f"{view_label(view)} · {label}", origin=f"/stats/{view}/{stat}")
             for stat, label in STATS_LABELS.items() if contents.has(f"/stats/{view}/{stat}")]
    kinds = ("depth", "normal", "cost", "selected_count", "error", "counter")
    if contents.entities is not None and contents.has(f"/maps/{view}/confidence"):
        kinds += ("confidence", "label")
    # three panels a row: at 1280 px a panel's title bar has room for "003 · " and a label of MAP_LABELS or
    # STATS_LABELS beside its buttons (four or six a row cut them to "003 · de")
    rows = [rrb.Grid(*[map_panel(contents, view, kind) for kind in kinds], grid_columns=3)]
    if stats:
        rows.append(rrb.Grid(*stats, grid_columns=3))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*rows, row_shares=[2, 1][:len(rows)]),
            rrb.Vertical(rrb.Spatial3DView(name="scene", origin="/world"),
                         rrb.Tabs(rrb.TextDocumentView(name="legend", origin="/legend", contents="$origin"),
                                  rrb.TextDocumentView(name="about this recording", origin="/about",
                                                       contents="$origin"),
                                  rrb.TextLogView(name="log", origin="/log")),
                         row_shares=[1, 1]),
            column_shares=[3, 2],
        ),
        *_panels(contents),
    )


def pipelines(contents: Contents, view: str) -> rrb.Blueprint:
    clouds = [rrb.Spatial3DView(name=f"fused cloud · {name}", origin="/world",
                                contents=["/world/cameras/**", f"/world/fused/{name}"])
              for name in PIPELINES if contents.has(f"/world/fused/{name}")]
    clouds += [rrb.Spatial3DView(name=f"mesh · {name}", origin="/world",
                                 contents=["/world/cameras/**", f"/world/mesh/{name}"])
               for name in PIPELINES if contents.entities is not None and contents.has(f"/world/mesh/{name}")]
    if not clouds:
        clouds = [rrb.TextDocumentView(name="fused clouds: not recorded", origin="/missing/fused")]
    return rrb.Blueprint(
        rrb.Vertical(
            # clouds over meshes, three a row at most (seven panels a row cut their titles at 1280 px)
            rrb.Horizontal(rrb.Grid(*clouds, grid_columns=min(3, len(clouds))), _text_panels(),
                           column_shares=[3, 1]),
            rrb.Horizontal(*[map_panel(contents, view, kind) for kind in ("depth", "confidence", "error")]),
            row_shares=[2, 1],
        ),
        *_panels(contents, "collapsed"),
    )


def _confidence_tab(contents: Contents, view: str):
    return rrb.Grid(
        rrb.Spatial2DView(name=f"{view_label(view)} · image", origin=f"/world/cameras/{view}/rgb"),
        map_panel(contents, view, "confidence"),
        map_panel(contents, view, "label"),
        map_panel(contents, view, "error"),
        name=view_title(view),
    )


def confidence(contents: Contents, view: str) -> rrb.Blueprint:
    tabs = [_confidence_tab(contents, v) for v in contents.views]
    active = contents.views.index(view) if view in contents.views else 0
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Tabs(*tabs, active_tab=active), _text_panels(), column_shares=[3, 1]),
        *_panels(contents, "collapsed"),
    )


def probed_pixels(contents: Contents, view: str) -> list[str]:
    """The ``<x>_<y>`` of every probed pixel of ``view`` the recording holds, in reading order."""
    prefix = f"/probe/{view}/"
    found = {path[len(prefix):].split("/", 1)[0] for path in contents.entities or () if path.startswith(prefix)}
    return sorted(found, key=lambda xy: tuple(int(c) for c in xy.split("_")[::-1]) if "_" in xy else (0, 0))


def _probe_tab(view: str, xy: str):
    base = f"/probe/{view}/{xy}"
    return rrb.Horizontal(
        rrb.Vertical(rrb.TimeSeriesView(name=f"cost · pixel {xy}", origin=f"{base}/cost"),
                     rrb.TimeSeriesView(name=f"depth and GT · pixel {xy}", origin=base,
                                        contents=[f"{base}/depth", f"{base}/gt_depth"]),
                     rrb.Spatial2DView(name="window in each source image", origin=f"{base}/windows")),
        rrb.Vertical(rrb.Spatial3DView(name="candidates on the pixel's ray", origin="/",
                                       contents=["/world/**", f"{base}/candidates", f"{base}/ray", f"{base}/gt"]),
                     rrb.Tabs(rrb.TextDocumentView(name="candidates", origin=f"{base}/candidates_table"),
                              rrb.TextDocumentView(name="final estimate", origin=f"{base}/summary"))),
        name=f"pixel {xy.replace('_', ', ')}")


def probe(contents: Contents, view: str) -> rrb.Blueprint:
    pixels = probed_pixels(contents, view)
    tabs = [_probe_tab(view, xy) for xy in pixels] or [
        rrb.TextDocumentView(name=f"no probed pixel of {view_title(view)}", origin=f"/missing/{view}/probe")]
    maps = [map_panel(contents, view, kind) for kind in ("depth", "error") if contents.has(f"/maps/{view}/{kind}")]
    main = rrb.Tabs(*tabs) if len(tabs) > 1 else tabs[0]
    return rrb.Blueprint(
        rrb.Horizontal(main, rrb.Vertical(*maps, _text_panels()), column_shares=[3, 1]) if maps else main,
        *_panels(contents, "expanded"),
    )


LAYOUTS: dict[str, Callable[[Contents, str], rrb.Blueprint]] = {
    "iterations": iterations,
    "pipelines": pipelines,
    "confidence": confidence,
    "probe": probe,
}
DEFAULT = "iterations"


#: the maps ``compare`` sets side by side, those either recording holds, in this order
COMPARE_KINDS = ("depth", "error", "confidence", "label", "cost", "normal", "counter", "refined_depth")


def _side_panel(contents: Contents, side: str, view: str, kind: str):
    """``maps/<view>/<kind>`` of the recording re-logged under ``/<side>`` (``deepc replay A --compare B``)."""
    label = f"{side.upper()} · {view_label(view)} · {MAP_LABELS.get(kind, kind)}"
    if contents.has(f"/maps/{view}/{kind}"):
        return rrb.Spatial2DView(name=label, origin=f"/{side}/maps/{view}/{kind}")
    return rrb.TextDocumentView(name=f"{label}: not recorded", origin=f"/{side}/missing/{view}/{kind}")


def compare(a: Contents, b: Contents, view: str) -> rrb.Blueprint:
    """Two recordings merged under ``/a`` and ``/b``: one tab per view both hold (``view``'s open), each map of A
    beside the same map of B, a row per map; one timeline scrubs both (their iterations share it)."""
    views = [v for v in a.views if v in b.views]
    tabs = []
    for v in views:
        kinds = [k for k in COMPARE_KINDS if a.has(f"/maps/{v}/{k}") or b.has(f"/maps/{v}/{k}")]
        rows = [rrb.Horizontal(_side_panel(a, "a", v, k), _side_panel(b, "b", v, k)) for k in kinds]
        tabs.append(rrb.Vertical(*rows, name=view_title(v)))
    active = views.index(view) if view in views else 0
    return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=active), *_panels(a, "collapsed"))
