"""The viewer's layout (a Rerun blueprint): per simulator its robot in 3D, a plot per state group
(the states against their reference), the inputs and the MPC's solve time and plan; beside them
the training losses, collection progress and the run's log."""

from __future__ import annotations

from collections.abc import Mapping

import rerun.blueprint as rrb

from .logger import SimLayout, path_chunk

__all__ = ["layout"]


def _sim_tab(sim: str, lay: SimLayout) -> rrb.Container:
    s = path_chunk(sim)
    plots: list[rrb.View] = [
        rrb.TimeSeriesView(origin=f"/control/{s}/state/{g}", name=f"{sim}: {g} (and reference)") for g, _ in lay.groups
    ]
    plots.append(rrb.TimeSeriesView(origin=f"/control/{s}/input", name=f"{sim}: inputs"))
    side: list[rrb.View] = []
    if lay.robot is not None:
        side.append(rrb.Spatial3DView(origin=f"/robot/{s}", name=f"{sim} (reference: the blue ghost)"))
    side += [
        rrb.Spatial2DView(origin=f"/control/{s}/plan", name=f"{sim}: MPC plan (x̂ against seconds ahead)"),
        rrb.TimeSeriesView(origin=f"/control/{s}/solve_us", name=f"{sim}: solve time (µs)"),
    ]
    return rrb.Horizontal(rrb.Vertical(*plots), rrb.Vertical(*side), column_shares=[3, 2], name=sim)


def layout(sims: Mapping[str, SimLayout]) -> rrb.Blueprint:
    """The blueprint for the simulators seen so far (sent again when one appears)."""
    run = rrb.Vertical(
        rrb.TimeSeriesView(origin="/train", name="training (loss terms, validation)"),
        rrb.TimeSeriesView(origin="/run/collect", name="collection (windows)"),
        rrb.TextLogView(origin="/", contents=["/run/**", "/train/**", "/control/**"], name="run log"),
        name="run",
    )
    tabs = [_sim_tab(sim, lay) for sim, lay in sims.items()]
    main = rrb.Tabs(*tabs, name="simulators") if tabs else rrb.TextLogView(origin="/run", name="waiting for the closed loop")
    # One timeline for every plot: seconds since the viewer started (`step` aligns the loops).
    return rrb.Blueprint(rrb.Horizontal(main, run, column_shares=[3, 1]), rrb.TimePanel(timeline="wall"), collapse_panels=True)
