"""What each plot draws, computed from a scene in a background thread (no Textual here).

A plot states what it wants (a DOF and quantity, an equation, a frame time) and one of these
functions answers from a scene snapshot off the UI thread (see background.py), so plots only
render: the UI thread never compiles or evaluates a term. Compiling basketball's expressions
for the Expr plot once held every key for more than a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from stw_tui.session.queries import Series, dof_series, equation_series

if TYPE_CHECKING:
    from stw_tui.session.figure import Figure
    from stw_tui.sos.scene import Scene

Bounds = tuple[float, float, float, float]


@dataclass(frozen=True)
class DofPlotData:
    """One DOF's value, velocity or acceleration, with the window and keyframes to mark."""

    name: str
    order: int
    series: Series
    span: tuple[float, float]
    window: str
    interval: tuple[float, float] | None
    inside: bool                   # the DOF is in the active window
    keys: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class ExpressionPlotData:
    """The values of each relation or term of a constraint, objective or subexpression."""

    name: str
    series: tuple[Series, ...]
    scope: tuple[float, float] | None
    span: tuple[float, float]


@dataclass(frozen=True)
class FigureData:
    """The stick figure at time ``t``; ``bounds`` only for a lone DOF drawn as a dot (a figure
    uses the bounds the worker measured over the whole span)."""

    t: float
    span: tuple[float, float]
    segments: tuple = ()
    points: tuple = ()
    bounds: Bounds | None = None
    ghost: "Figure | None" = None   # the proposal's figure at ``t`` under `set preview on`


def live_scene(scene: "Scene", coefficients) -> "Scene":
    """``scene`` with a running solve's control points (a copy), or ``scene`` itself when there
    are none or they no longer fit its curves."""
    if coefficients is None or len(coefficients) != scene.coefficient_vector().size:
        return scene
    live = scene.copy()
    live.with_coefficients(np.asarray(coefficients, float))
    return live


def dof_plot_data(scene: "Scene", name: str, order: int) -> DofPlotData:
    """A DOF's curve (value, velocity or acceleration), its keys and its window, for the curve plot."""
    window = scene.window
    keys = tuple((float(t), float(v)) for t, v in scene.dofs[name].keys) if order == 0 else ()
    return DofPlotData(name, order, dof_series(scene, name, order), (scene.t0, scene.t1), window.name,
                       window.interval, window.dofs is None or name in window.dofs, keys)


def expression_plot_data(scene: "Scene", name: str) -> ExpressionPlotData:
    """Raises StwError for an expression that no longer compiles (the plot says so)."""
    series, scope = equation_series(scene, name)
    return ExpressionPlotData(name, tuple(series), scope, (scene.t0, scene.t1))


def figure_data(scene: "Scene", t: float, proposal=None) -> FigureData:
    """The figure player's frame at ``t`` (clamped to the span); with a ProposalView, the proposed
    motion's figure beside it. Computed off the UI thread: it evaluates the scene's curves."""
    from stw_tui.session.figure import player_figure, point_pairs

    t = min(max(t, scene.t0), scene.t1)
    figure = player_figure(scene, t)
    span = (scene.t0, scene.t1)
    ghost = proposal.figure(t) if proposal is not None else None
    if scene.linkages or point_pairs(scene) or not figure.points:
        return FigureData(t, span, tuple(figure.segments), tuple(figure.points), ghost=ghost)
    # A lone DOF (the jet particle), which player_figure draws as a dot at its height: keep the
    # plot's range to the whole curve's, so the dot moves instead of the axes. Not the worker's
    # figure_bounds, as a figure uses: those are the scene's after the last command, and a solve
    # moves the dot out of them (a new jet's flat start gives +-0.02); one curve is cheap to
    # measure on the live scene (the jet's whole figure_data: 0.7 ms; a linkage's figure_bounds: 60-150 ms).
    values = dof_series(scene, figure.points[0][0], 0).values
    pad = 0.1 * max(max(values) - min(values), 0.2)
    return FigureData(t, span, points=tuple(figure.points),
                      bounds=(-1.0, 1.0, min(values) - pad, max(values) + pad), ghost=ghost)

