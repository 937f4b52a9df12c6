"""Queries for views: the numbers the TUI shows, computed from a scene (no Textual; safe in a worker).

Everything here only *reads* a scene; nothing changes one. The functions are called either on the
UI thread for cheap things (a DOF curve) or in the session worker after each command for the
ones that compile or build a window problem (violations, figure bounds).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from typing import TYPE_CHECKING

import numpy as np

from stw_tui.sym.kinds import TermKind

if TYPE_CHECKING:
    from stw_tui.session.figure import Figure
    from stw_tui.session.snapshots import Measures
    from stw_tui.sos.continuous import DenseReport
    from stw_tui.sos.scene import Scene

QUANTITIES = ("value", "velocity", "acceleration")


@dataclass
class Series:
    """One curve over time, with a label for the legend."""

    label: str
    times: list[float]
    values: list[float]


@dataclass
class SceneInfo:
    """What the worker measured about a scene after a command (shown by panels and plots)."""

    violations: dict[str, float] = field(default_factory=dict)
    backend_options: tuple = ()          # BackendOption records of the scene's backend
    backend_error: str = ""
    figure_bounds: tuple[float, float, float, float] | None = None   # with a proposal: of both
    proposal: "ProposalView | None" = None     # a solve's result under `set preview on`
    measures: "SceneMeasures | None" = None    # what the status line shows (None: not measured)


@dataclass(frozen=True)
class SceneMeasures:
    """How good the scene's motion is now, in the numbers the status line shows: the objective
    over the whole animation, the largest violation at the constraint instances and anywhere
    (the continuous-time check, the one that counts), and the check that is worst there."""

    objective: float | None      # None: the objective cannot be evaluated (a broken term)
    instances: float | None      # None: the constraints cannot be checked (a broken term)
    dense: float | None
    worst: str = ""              # the worst check's name, where the dense violation fails
    worst_t: float | None = None


def dof_series(scene: "Scene", name: str, order: int, n: int = 161) -> Series:
    """Value (order 0), velocity (1) or acceleration (2) of a DOF over the span."""
    times = np.linspace(scene.t0, scene.t1, n)
    values = scene.dof_values(name, times, order)
    return Series(f"{name}{chr(39) * order}", times.tolist(), values.tolist())


def equation_names(scene: "Scene") -> list[str]:
    """Names whose values can be plotted over time: constraints, objectives, subexpressions."""
    return [*scene.constraints, *scene.objectives, *scene.lets]


def equation_series(scene: "Scene", name: str, n: int = 161) -> tuple[list[Series], tuple[float, float] | None]:
    """Values over the span of each relation or term of a constraint, objective or subexpression.

    Returns:
        The curves and the time scope to mark (an instant is returned as (t, t); None: the span).
    Raises:
        StwError: an expression that no longer compiles (e.g. a deleted name).
    """
    from stw_tui.sym.symbols import named_symbol

    times = np.linspace(scene.t0, scene.t1, n)
    if name in scene.constraints:
        c = scene.constraints[name]
        scope = c.span
        out = []
        for i, rel in enumerate(c.relations, start=1):
            label = f"{name}[{i}] {'= 0' if rel.kind == TermKind.EQ else '>= 0'}"
            out.append(Series(label, times.tolist(), scene.evaluate(rel.expr, times).tolist()))
        return out, scope
    if name in scene.objectives:
        o = scene.objectives[name]
        return [Series(f"{name}[{i}]", times.tolist(), scene.evaluate(e, times).tolist())
                for i, e in enumerate(o.exprs, start=1)], o.interval
    return [Series(name, times.tolist(), scene.evaluate(named_symbol(name), times).tolist())], None


def equation_violations(scene: "Scene", dense: "DenseReport | None" = None) -> dict[str, float]:
    """Max violation of every constraint over its whole scope, between instances too (the
    continuous-time check), whatever window is in use ({} when a constraint no longer compiles).
    ``dense``: that check of ``scene`` already made (an `iterate`'s, Outcome.dense)."""
    return _violations(dense_check(scene, dense))


def _violations(report: "DenseReport | None") -> dict[str, float]:
    """Each check's largest violation anywhere, by name ({} without a report)."""
    return {} if report is None else {name: c.dense for name, c in report.checks.items()}


def dense_check(scene: "Scene", dense: "DenseReport | None" = None) -> "DenseReport | None":
    """The continuous-time check of ``scene`` (``dense`` when already made), or None when there
    is nothing to check or a constraint no longer compiles (e.g. it names a deleted definition)."""
    if dense is not None:
        return dense
    if not scene.constraints or not scene.dofs:
        return None
    try:
        from stw_tui.sos.continuous import check_scene

        return check_scene(scene)
    except Exception:  # a half-built scene has no check
        return None


def scene_measures(scene: "Scene", dense: "DenseReport | None") -> "SceneMeasures | None":
    """The status line's numbers for ``scene`` (in the worker: it builds the whole animation's
    window problem, ~0.1-20 ms on the bundled sessions). ``dense``: its continuous-time check
    (None: nothing to check, or it failed). None when the scene has no DOF."""
    if not scene.dofs:
        return None
    objective = None
    try:
        from stw_tui.sos.window import WindowProblem

        problem = WindowProblem.of(scene, "all")
        objective = float(problem.merit_values(problem.initial()).objective)
    except Exception:  # a broken term: the violations are still worth showing
        objective = None
    if objective is not None and not np.isfinite(objective):
        objective = None
    if dense is None:   # no constraint (DOF bounds hold everywhere: on the control points), or a broken one
        return SceneMeasures(objective, None, None) if scene.constraints else SceneMeasures(objective, 0.0, 0.0)
    failing = dense.failing(float(scene.settings["dense_tol"]))
    worst = failing[0] if failing else None
    return SceneMeasures(objective, float(dense.instance_violation), float(dense.dense_violation),
                         worst.name if worst is not None else "", worst.worst_t if worst is not None else None)


def figure_bounds(scene: "Scene", frames: int = 11, proposal: "Scene | None" = None
                  ) -> tuple[float, float, float, float] | None:
    """Bounds of the stick figure over the whole span, so playback does not rescale the axes; of
    the proposal's figure too when one is shown beside it."""
    from stw_tui.session.figure import player_figure

    scenes = [scene] if proposal is None else [scene, proposal]
    try:
        boxes = [player_figure(s, t).bounds() for s in scenes for t in np.linspace(s.t0, s.t1, frames)]
    except Exception:  # drawing is best effort; a broken figure must not break the session
        return None
    x0, x1 = min(b[0] for b in boxes), max(b[1] for b in boxes)
    y0, y1 = min(b[2] for b in boxes), max(b[3] for b in boxes)
    pad_x, pad_y = 0.1 * max(x1 - x0, 0.2), 0.1 * max(y1 - y0, 0.2)
    if x1 == x0:     # a dot moving up and down (the jet particle): a unit box around it
        pad_x = 1.0
    return (x0 - pad_x, x1 + pad_x, y0 - pad_y, y1 + pad_y)


@dataclass
class ProposalView:
    """A solve's proposed motion (`set preview on`) and how it compares with the scene's: the
    figure player draws the proposal beside the scene's motion, which it dims."""

    scene: "Scene"
    proposed: "Measures"
    current: "Measures"

    def figure(self, t: float) -> "Figure":
        """The proposed motion's stick figure at ``t`` (its lone DOF as a dot, as the player draws it)."""
        from stw_tui.session.figure import player_figure

        return player_figure(self.scene, t)

    def captions(self, t: float) -> tuple[str, ...]:
        """Titles for the player, most detailed first: objective and violation of both."""
        p, c = self.proposed, self.current
        if p.objective is None or c.objective is None:
            return (f"t = {t:.3f} · proposal (F9 accept, F10 reject), now dimmed",
                    f"t = {t:.3f} · proposal, now dimmed", f"t={t:.2f} proposal")
        new, now = f"obj {p.objective:.4g} viol {p.dense:.1e}", f"obj {c.objective:.4g} viol {c.dense:.1e}"
        return (f"t = {t:.3f} · proposal {new} · now (dim) {now} · F9 accept, F10 reject",
                f"t = {t:.3f} · proposal {new} · now (dim) {now}",
                f"proposal {new} · now {now}",
                f"obj {p.objective:.4g} (now {c.objective:.4g}) · viol {p.dense:.1e} (now {c.dense:.1e})",
                f"obj {p.objective:.3g} ({c.objective:.3g}) viol {p.dense:.0e} ({c.dense:.0e})",
                f"t={t:.2f} proposal")


def proposal_view(scene: "Scene", proposal: "Scene") -> ProposalView:
    """Measure a proposal and the scene it would replace (in the worker: it builds window problems)."""
    from stw_tui.session.snapshots import measure

    return ProposalView(proposal, measure(proposal), measure(scene))


def scene_info(scene: "Scene", proposal: "Scene | None" = None,
               dense: "DenseReport | None" = None) -> SceneInfo:
    """Everything slow the panels need, measured once per command (called in the worker); with
    the scene a solve proposes under `set preview on`, what the figure player shows of it.
    ``dense``: the continuous-time check of ``scene`` the command made (Outcome.dense), if any."""
    report = dense_check(scene, dense)
    info = SceneInfo(violations=_violations(report),
                     figure_bounds=figure_bounds(scene, proposal=proposal),
                     measures=scene_measures(scene, report))
    if proposal is not None:
        info.proposal = proposal_view(scene, proposal)
    try:
        from stw_tui.sos.backend import load_backend

        info.backend_options = tuple(load_backend(scene.backend).options)
    except Exception as exc:  # a broken plugin is shown in the panel, not raised
        info.backend_error = str(exc)
    return info
