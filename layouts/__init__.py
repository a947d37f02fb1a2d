"""Rerun blueprints, one per debugging task. Change what you see here, not in engine code.

Each layout is a function of the view entity names present in a recording (``maps/<view>/...``)
returning an ``rrb.Blueprint``:

- ``iterations``: PatchMatch iterations of one view — depth, normals, cost, selected views, error
  against GT, and the per-iteration scalars, with the cameras in 3-D.
- ``pipelines``: the fused clouds of the pipelines side by side with one view's maps.
- ``confidence``: confidence against label maps and depth error, per view.
"""

from __future__ import annotations

from collections.abc import Callable

import rerun.blueprint as rrb


def iterations(views: list[str], focus: int = 0) -> rrb.Blueprint:
    view = views[min(focus, len(views) - 1)]
    maps = f"/maps/{view}"
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Grid(
                    rrb.Spatial2DView(name="depth", origin=f"{maps}/depth"),
                    rrb.Spatial2DView(name="normal", origin=f"{maps}/normal"),
                    rrb.Spatial2DView(name="cost", origin=f"{maps}/cost"),
                    rrb.Spatial2DView(name="selected views", origin=f"{maps}/selected_count"),
                    rrb.Spatial2DView(name="error vs GT", origin=f"{maps}/error"),
                    rrb.Spatial2DView(name="counter", origin=f"{maps}/counter"),
                ),
                rrb.Horizontal(
                    rrb.TimeSeriesView(name="mean cost", origin=f"/stats/{view}/mean_cost"),
                    rrb.TimeSeriesView(name="changed %", origin=f"/stats/{view}/changed_pct"),
                    rrb.TimeSeriesView(name="within 1 % of GT", origin=f"/stats/{view}/within_1pct"),
                ),
                row_shares=[3, 1],
            ),
            rrb.Vertical(rrb.Spatial3DView(name="scene", origin="/world"), rrb.TextLogView(name="log", origin="/log"),
                         row_shares=[3, 1]),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
    )


def pipelines(views: list[str], focus: int = 0) -> rrb.Blueprint:
    view = views[min(focus, len(views) - 1)]
    clouds = [rrb.Spatial3DView(name=name, origin="/world", contents=["/world/cameras/**", f"/world/fused/{name}"])
              for name in ("vanilla", "fast", "full")]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*clouds),
            rrb.Horizontal(
                rrb.Spatial2DView(name="depth", origin=f"/maps/{view}/depth"),
                rrb.Spatial2DView(name="confidence", origin=f"/maps/{view}/confidence"),
                rrb.Spatial2DView(name="refined depth", origin=f"/maps/{view}/refined_depth"),
                rrb.Spatial2DView(name="error vs GT", origin=f"/maps/{view}/error"),
            ),
            row_shares=[2, 1],
        ),
        rrb.TimePanel(state="collapsed"),
    )


def confidence(views: list[str], focus: int = 0) -> rrb.Blueprint:
    rows = []
    for view in views[:4]:
        rows.append(rrb.Horizontal(
            rrb.Spatial2DView(name=f"{view} image", origin=f"/world/cameras/{view}/rgb"),
            rrb.Spatial2DView(name="confidence", origin=f"/maps/{view}/confidence"),
            rrb.Spatial2DView(name="labels", origin=f"/maps/{view}/label"),
            rrb.Spatial2DView(name="error vs GT", origin=f"/maps/{view}/error"),
        ))
    return rrb.Blueprint(rrb.Vertical(*rows), rrb.TimePanel(state="collapsed"))


LAYOUTS: dict[str, Callable[..., rrb.Blueprint]] = {
    "iterations": iterations,
    "pipelines": pipelines,
    "confidence": confidence,
}
DEFAULT = "iterations"
