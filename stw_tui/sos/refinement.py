"""Adaptive refinement: where the continuous-time check fails, knots for the curves, not only
instances.

A relation imposed at instances about as dense as the knots of the DOF it reads fails between
them because the curves lack the freedom to follow it there (a cubic B-spline ball tied to the
tip of a linkage, whose path is no cubic): more instances only over-determine those curves, and
the re-solve cannot meet them. Inserting knots (Boehm; the curve is unchanged, so the re-solve
starts where the last one ended) gives them that freedom, and instances on the knots of the
refined spans impose the relation where it was failing. This module decides, from the check's failing times, which
knot spans of which DOF to halve and which instances to add; the session applies them as the
`refine` and `instances` lines a journal replays.

Instances alone stay where they are enough:

- an inequality (a floor, a joint range): it binds at a few points and over-determines nothing,
  and a finer curve only dips further between its instances (point_mass_2d's floor: 3 instances
  hold it to 5e-9; refining instead left 1e-5 after 4 rounds);
- a relation whose instances are sparser than the knots of the DOF it reads (`samples=` below
  the knot count): the curves can follow already; what is missing is a place to impose it;
- a relation linear in the DOF with constant coefficients (``q1 - q2 = 0``, ``BY'' + g = 0``):
  instances on the knots make it exact, so instances are enough even where `samples=` placed
  them otherwise (the bench's coupled DOF: refined, its re-solve hit the iteration limit and
  was undone at 1.3e-3; with instances, it holds to 1e-6); a constraint ``@ t``; DOF bounds;
- failing times outside the window's interval: new control points there would not be free;
- a DOF over the control-point budget (``adaptive_points``) or the knot limit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stw_tui.sos.instances import dofs_used, exact_degree, relation_times
from stw_tui.sym import limits
from stw_tui.sym.kinds import TermKind

# A relation's instances count as "about as dense as the knots" (so that more of them would
# over-determine the curves) when the spans to refine hold at least this many instances a span
# (uniform samples at the knot density: about 1; `samples=` at a third of it: 1/3).
DENSE_ENOUGH = 0.6
# The spans refined in a round are those around the failing peaks within this factor of the
# check's worst (the "maximum strategy" of adaptive mesh refinement, Babuska and Rheinboldt):
# the rounds and the budget go where the motion is worst, not to every gap a little over the
# tolerance.
MARK = 0.1


@dataclass
class RefinementPlan:
    """One adaptive round's changes: knot spans to halve per DOF, instances to add per check."""

    spans: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    instances: dict[str, np.ndarray] = field(default_factory=dict)
    refined_for: dict[str, tuple[str, ...]] = field(default_factory=dict)   # check -> DOF refined
    over_budget: list[str] = field(default_factory=list)   # checks left unrefined by the budget
    added_points: int = 0

    def lines(self) -> list[str]:
        """The `refine` lines, then the `instances` lines, that make this plan (and replay it)."""
        out = [f"refine {dof} [{a!r}, {b!r}]" for dof, runs in self.spans.items() for a, b in runs]
        out += [f"instances {name} add " + ", ".join(repr(float(t)) for t in times)
                for name, times in self.instances.items()]
        return out

    def __bool__(self) -> bool:
        return bool(self.spans or self.instances)


def plan_round(scene, failing: dict[str, np.ndarray], wanted: dict[str, np.ndarray],
               free_dofs, interval: tuple[float, float], reach: tuple[float, float],
               budget: int) -> RefinementPlan:
    """What one adaptive round changes.

    Args:
        scene: the scene as the last solve left it.
        failing: per check, the times where its dense violation peaks above its tolerance
            (continuous.survey_failures).
        wanted: per check, the instances the check proposes (one per failing gap).
        free_dofs: the DOF the window frees.
        interval: the window's interval (knots are inserted only inside it).
        reach: the times the window's free control points can change (instances only there).
        budget: the most control points the scene may have after this round.
    Returns:
        The plan (empty: nothing would help).
    """
    plan = RefinementPlan()
    total = sum(dof.curve.n_coef for dof in scene.dofs.values())
    lo, hi = reach
    span = scene.t1 - scene.t0
    # the worst checks first: the budget goes to them
    worst = {name: float(peaks[:, 1].max()) for name, peaks in failing.items()}
    for name in sorted(set(failing) | set(wanted), key=lambda n: -worst.get(n, 0.0)):
        peaks = failing.get(name, np.zeros((0, 2)))
        times = peaks[peaks[:, 1] >= MARK * worst.get(name, 0.0), 0]
        runs = _runs_for(scene, name, times, free_dofs, interval, plan.spans)
        added = sum(len(r) for r in runs.values())
        fits = all(_within_knot_limit(scene.dofs[d].curve, r, plan.spans.get(d, [])) for d, r in runs.items())
        if runs and (total + plan.added_points + added > budget or not fits):
            plan.over_budget.append(name)
            runs = {}
        if runs:
            for dof, spans in runs.items():
                plan.spans.setdefault(dof, []).extend(spans)
            plan.added_points += added
            plan.refined_for[name] = tuple(runs)
            # instances on every knot of the refined spans, old and new: each span of the
            # refined curves gets the relation at both its ends
            constraint = scene.constraints[name]
            a, b = constraint.interval
            knots = np.unique(np.concatenate([_knots_of(r) for r in runs.values()]))
            times = knots[(knots >= a) & (knots <= b)]
        else:   # not refined: an instance in each gap where it fails (as before refinement)
            times = np.asarray(wanted.get(name, ()), float)
        times = times[(times >= lo) & (times <= hi)]
        have = _instances_of(scene, scene.constraints[name]) if name in scene.constraints else np.zeros(0)
        times = np.array([t for t in times if not have.size or np.min(np.abs(have - t)) > 1e-9 * span])
        if times.size:
            plan.instances[name] = times
    for dof in plan.spans:
        plan.spans[dof] = _merged(plan.spans[dof])
    return plan


def _runs_for(scene, name: str, times: np.ndarray, free_dofs, interval, planned) -> dict[str, list]:
    """Per DOF that the check's failing relations read (and the window frees), the knot spans
    to halve: each span holding a failing time inside the window, and its neighbours. Empty
    when refinement does not apply (see the module's docstring)."""
    constraint = scene.constraints.get(name)
    if constraint is None or constraint.at is not None or not times.size:
        return {}
    a, b = constraint.interval
    # (a relation linear in the DOF with constant coefficients is met exactly by instances on
    # the knots, even where `samples=` places them otherwise: instances are enough for it)
    exprs = [rel.expr for rel in constraint.relations
             if rel.kind == TermKind.EQ and exact_degree(scene, rel.expr, rel.kind, (a, b)) is None]
    wa, wb = interval
    times = times[(times >= max(a, wa)) & (times <= min(b, wb))]
    if not exprs or not times.size:
        return {}
    dofs = [d for d in dofs_used(scene, exprs, (a, b)) if d in free_dofs]
    if not dofs:
        return {}
    instances = _instances_of(scene, constraint, exprs)
    runs = {}
    for dof in dofs:
        bp = scene.dofs[dof].curve.breakpoints
        hit = np.unique(np.clip(np.searchsorted(bp, times, side="right") - 1, 0, bp.size - 2))
        hit = np.unique(np.clip(np.concatenate([hit - 1, hit, hit + 1]), 0, bp.size - 2))
        # inside the window: a span reaching past it would make control points the window does not free
        spans = [(float(bp[i]), float(bp[i + 1])) for i in hit if bp[i] >= wa - 1e-12 and bp[i + 1] <= wb + 1e-12]
        done = planned.get(dof, [])
        spans = [s for s in spans if s not in done]
        if spans:
            runs[dof] = spans
    # Instances sparser than the knots there (`samples=` below the knot count): the curves can
    # follow already, and an instance where it fails is what is missing.
    inside = [np.count_nonzero((instances >= max(u, a)) & (instances <= min(v, b))) / (min(v, b) - max(u, a))
              * (v - u) for spans in runs.values() for u, v in spans if min(v, b) > max(u, a)]
    if inside and np.mean(inside) < DENSE_ENOUGH:
        return {}
    return runs


def _instances_of(scene, constraint, exprs=None) -> np.ndarray:
    """The instance times of a constraint's relations (of those in ``exprs`` when given)."""
    if constraint.at is not None:
        return np.array([constraint.at])
    found = [relation_times(scene, constraint, rel.expr, rel.kind) for rel in constraint.relations
             if exprs is None or rel.expr in exprs]
    return np.unique(np.concatenate(found)) if found else np.zeros(0)


def _knots_of(spans) -> np.ndarray:
    """The knots of these spans once halved: their ends and midpoints (DofCurve.refined's)."""
    lo = np.array([a for a, _ in spans])
    hi = np.array([b for _, b in spans])
    return np.concatenate([lo, hi, lo + (hi - lo) * 0.5])


def _within_knot_limit(curve, spans, planned) -> bool:
    return curve.spans + len(spans) + len(planned) <= limits.value("knots")


def _merged(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Adjacent or overlapping spans joined into runs, in time order."""
    out: list[list[float]] = []
    for a, b in sorted(set(spans)):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


@dataclass
class RefinementLog:
    """What the adaptive rounds of one solve did, for its summary: the DOF refined and where, the
    instances added, the control points before and after, and what stopped them."""

    points_before: int
    budget: int
    points: int = 0
    refined: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    refined_for: dict[str, set[str]] = field(default_factory=dict)   # check -> DOF refined for it
    added: dict[str, int] = field(default_factory=dict)
    over_budget: set[str] = field(default_factory=set)
    undone: str = ""              # "; undid a re-solve …" (empty when none was undone)
    rounds_out: bool = False      # adaptive_rounds ran out while a check still failed

    def keep(self, plan: RefinementPlan) -> None:
        """A round whose re-solve converged: its changes stay."""
        for dof, runs in plan.spans.items():
            self.refined[dof] = _merged(self.refined.get(dof, []) + runs)
        for name, dofs in plan.refined_for.items():
            self.refined_for.setdefault(name, set()).update(dofs)
        for name, times in plan.instances.items():
            self.added[name] = self.added.get(name, 0) + int(times.size)

    def undo(self, plan: RefinementPlan, status: str, iterations: int) -> None:
        """A round whose re-solve did not converge, and was undone."""
        what = []
        if plan.spans:
            what.append(f"{plan.added_points} more control point(s) ({', '.join(plan.spans)})")
        count = sum(t.size for t in plan.instances.values())
        if count:
            what.append(f"{count} more instance(s) ({', '.join(plan.instances)})")
        self.undone = f"; undid a re-solve with {' and '.join(what)}: {status} after {iterations} iteration(s)"

    def describe(self) -> str:
        """'; refined SHOULDER, BX over [0, 0.125] (135 -> 141 control points); added 4 …'."""
        text = ""
        if self.refined:
            by_runs: dict[tuple, list[str]] = {}
            for dof, runs in self.refined.items():
                by_runs.setdefault(tuple(runs), []).append(dof)
            where = "; ".join(f"{', '.join(dofs)} over " + ", ".join(f"[{a:.4g}, {b:.4g}]" for a, b in runs)
                              for runs, dofs in by_runs.items())
            text += (f"; refined {where} for {', '.join(self.refined_for)} "
                     f"({self.points_before} -> {self.points} control points)")
        if self.added:
            text += (f"; added {sum(self.added.values())} instance(s) where it failed ("
                     + ", ".join(f"{n} {k}" for n, k in self.added.items()) + ")")
        return text

    def stop_note(self) -> str:
        """What stopped refinement while a check still fails (empty: nothing did)."""
        if self.over_budget:
            return (f"the control-point budget stopped refinement for {', '.join(sorted(self.over_budget))} "
                    f"(adaptive_points {self.budget}, {self.points} now; `set adaptive_points N` allows more)")
        if self.rounds_out:
            return "adaptive_rounds ran out (`iterate` again, or `set adaptive_rounds N`)"
        return ""
