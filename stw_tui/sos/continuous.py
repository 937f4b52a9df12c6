"""The continuous-time check: every constraint evaluated densely over its whole scope.

Instances are samples, and an optimizer exploits the gaps between them. After a solve, each
constraint (and each DOF bound) is evaluated over the whole animation at every instance, at least
``DENSE_PER_SPAN`` points in every knot span of the DOF it uses, and between every pair of
instances. Violations are scaled like the instance rows (the constraint's weight times its value),
so ``dense_tol`` compares with the same numbers as ``tol_violation``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import sympy as sp

from stw_tui.sos.instances import (bound_extra_times, bound_times, dofs_used, exact_degree, interval_cuts,
                                   kept_times, on_own_side, relation_instances, repeated_knots)
from stw_tui.sos.spline import SharedTimes
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.symbols import dof_symbol

DENSE_PER_SPAN = 8
MAX_PEAKS = 256          # local maxima of a relation's violation looked at more closely
SNAP = 2**14            # added instances lie on a lattice of 1/SNAP of the animation
REFINE_ROUNDS = 5        # each narrows a peak's bracket 8-fold: 1/8^5 of a grid step in the end


@dataclass(frozen=True)
class ConstraintCheck:
    """How well one constraint holds: at its instances, densely, and where it is worst."""

    name: str
    instances: float       # largest violation at the instance times
    dense: float           # largest violation of the motion anywhere on the dense grid (instances included;
                           # a bound's instances are its control points, which the curve stays within)
    worst_t: float | None  # where the dense violation is largest (None: it holds everywhere)
    tol: float | None = None   # the constraint's own dense_tol (None: the scene's)

    def as_dict(self) -> dict:
        """The check as JSON-ready data (for `print` and `stw run --json`)."""
        return {"instances": self.instances, "dense": self.dense, "worst_t": self.worst_t,
                **({"dense_tol": self.tol} if self.tol is not None else {})}

    def fails(self, default_tol: float) -> bool:
        """Whether the dense violation exceeds the constraint's own tolerance, or ``default_tol``."""
        return self.dense > (self.tol if self.tol is not None else default_tol)


@dataclass(frozen=True)
class DenseReport:
    """The continuous-time check of a whole scene."""

    checks: dict[str, ConstraintCheck]

    @property
    def dense_violation(self) -> float:
        """The largest violation anywhere on the dense grid, over all checks."""
        return max((c.dense for c in self.checks.values()), default=0.0)

    @property
    def instance_violation(self) -> float:
        """The largest violation at the instance times, over all checks."""
        return max((c.instances for c in self.checks.values()), default=0.0)

    def failing(self, tol: float) -> list[ConstraintCheck]:
        """Checks whose dense violation exceeds their tolerance (``tol`` unless the constraint
        has its own), worst first."""
        return sorted((c for c in self.checks.values() if c.fails(tol)), key=lambda c: -c.dense)

    def describe_failures(self, tol: float, limit: int = 3) -> str:
        """'in_hand 3.1e-04 at t=0.52, …' for the worst failures (empty when all hold)."""
        bad = self.failing(tol)
        text = ", ".join(f"{c.name} {c.dense:.1e} at t={c.worst_t:.4g}"
                         + (f" (its dense_tol {c.tol:.3g})" if c.tol is not None else "") for c in bad[:limit])
        return text + (f" and {len(bad) - limit} more" if len(bad) > limit else "")


def condition_holds(scene, when: sp.Basic | None, times: np.ndarray) -> np.ndarray:
    """Where a ``when`` condition holds on the scene's curves (all True without one)."""
    from stw_tui.sos.window import evaluate_condition_tree, numpy_filled, relation_nodes

    if when is None or when is sp.true:
        return np.ones(times.size, bool)
    leaves = {node: scene.evaluate(node.lhs - node.rhs, times) for node in relation_nodes(when)}
    return evaluate_condition_tree(when, leaves, numpy_filled(times.size))


def dense_times(scene, exprs, a: float, b: float, instances: np.ndarray) -> np.ndarray:
    """The check's grid on [a, b]: instances, their midpoints, and DENSE_PER_SPAN points in every
    knot span of the DOF the expressions use."""
    knots = [scene.dofs[n].curve.knots for n in dofs_used(scene, exprs)]
    breaks = np.unique(np.concatenate(knots or [[a, b]]))
    cuts = interval_cuts(breaks, a, b)
    fractions = np.linspace(0.0, 1.0, DENSE_PER_SPAN + 1)
    grid = (cuts[:-1, None] + (cuts[1:] - cuts[:-1])[:, None] * fractions[None, :]).ravel()
    mids = (instances[:-1] + instances[1:]) / 2 if instances.size > 1 else np.zeros(0)
    times = np.unique(np.concatenate([grid, instances, mids, [a, b]]))
    return np.unique(on_own_side(times, a, b, repeated_knots(knots)))


def _score(values: np.ndarray, kind: str, weight: float) -> np.ndarray:
    """Signed violation: positive where violated; for an inequality, how near it is to failing."""
    scaled = weight * values
    return np.abs(scaled) if kind == TermKind.EQ else -scaled


@dataclass(frozen=True)
class _Samples:
    """One relation's violations at its instances and on its dense grid (where it is active)."""

    t_inst: np.ndarray
    v_inst: np.ndarray
    t_grid: np.ndarray
    v_grid: np.ndarray
    exact: bool = False   # instances placed so that the relation holds everywhere (instances.py)


@dataclass
class _Sampling:
    """A relation (or a side of a DOF bound) to sample: its signed violation at part of a
    SharedTimes (``score``), its instances and the grid on which it is checked (None: at its
    instances only, a constraint ``@ t``). ``v_inst``: the violation at the instances when it is
    not the relation's own there (a bound's, on the control points)."""

    score: Callable[[SharedTimes, slice], np.ndarray]
    t_inst: np.ndarray
    t_base: np.ndarray | None
    exact: bool = False
    v_inst: np.ndarray | None = None


def _scores(samplings: list[_Sampling], times: list[np.ndarray], keep: bool = True) -> list[np.ndarray]:
    """Each sampling's score at its times, all evaluated on their concatenation (SharedTimes)."""
    shared = SharedTimes(np.concatenate(times) if times else np.zeros(0), keep)
    out, start = [], 0
    for sampling, t in zip(samplings, times):
        out.append(sampling.score(shared, slice(start, start + t.size)))
        start += t.size
    return out


def _sharpen(samplings: list[_Sampling], grids: list[np.ndarray], scores: list[np.ndarray],
             rounds: int = REFINE_ROUNDS) -> list[tuple[np.ndarray, np.ndarray]]:
    """Zoom in on the local maxima of each signed violation between grid points, where a tangency
    or a peak between samples hides (8 points a span find it only to within a sixteenth of a
    span). Returns per sampling the extra times looked at and their scores. The samplings zoom
    in together, a round at a time, each round one evaluation of them all (its times asked for
    once: their bases are not kept)."""
    brackets = []
    for t_grid, score in zip(grids, scores):
        if score.size < 2:
            brackets.append(None)
            continue
        left, right = np.r_[-np.inf, score[:-1]], np.r_[score[1:], -np.inf]
        peaks = np.flatnonzero((score >= left) & (score >= right))
        peaks = peaks[np.argsort(-score[peaks])][:MAX_PEAKS]
        brackets.append((t_grid[np.maximum(peaks - 1, 0)], t_grid[np.minimum(peaks + 1, t_grid.size - 1)]))
    live = [i for i, b in enumerate(brackets) if b is not None]
    seen: dict[int, list] = {i: [] for i in live}
    fractions = np.linspace(0.0, 1.0, 9) if live else None
    for _ in range(rounds if live else 0):
        times = [brackets[i][0][:, None] + (brackets[i][1] - brackets[i][0])[:, None] * fractions[None, :]
                 for i in live]
        values = _scores([samplings[i] for i in live], [t.ravel() for t in times], keep=False)
        for i, t, v in zip(live, times, values):
            lo, hi = brackets[i]
            v = v.reshape(t.shape)
            seen[i].append((t.ravel(), v.ravel()))
            best = np.argmax(v, axis=1)
            width = (hi - lo) / 8
            centre = t[np.arange(t.shape[0]), best]
            brackets[i] = np.maximum(lo, centre - width), np.minimum(hi, centre + width)
    empty = (np.zeros(0), np.zeros(0))
    return [(np.concatenate([t for t, _ in seen[i]]), np.concatenate([v for _, v in seen[i]]))
            if i in seen else empty for i in range(len(samplings))]


def _sample(samplings: list[_Sampling]) -> list[_Samples]:
    """Every sampling's violations at its instances and on its grid, sharpened at peaks. The
    instances and the grids are evaluated in one call (each instance on its own, the same
    numbers), and so is each round of sharpening: a call's fixed cost was most of the check."""
    both = _scores(samplings, [s.t_inst if s.t_base is None else np.concatenate([s.t_base, s.t_inst])
                               for s in samplings])
    dense = [i for i, s in enumerate(samplings) if s.t_base is not None]
    grids = [samplings[i].t_base for i in dense]
    bases = [both[i][:samplings[i].t_base.size] for i in dense]
    more = dict(zip(dense, _sharpen([samplings[i] for i in dense], grids, bases)))
    out = []
    for i, (s, score) in enumerate(zip(samplings, both)):
        if s.t_base is None:   # an instant: its instances are its grid
            v_inst = np.maximum(0.0, score)
            out.append(_Samples(s.t_inst, v_inst, s.t_inst, v_inst))
            continue
        base, at_instances = score[:s.t_base.size], score[s.t_base.size:]
        t_more, v_more = more[i]
        t_grid = np.concatenate([s.t_base, t_more])
        order = np.argsort(t_grid, kind="stable")
        v_grid = np.maximum(0.0, np.concatenate([base, v_more]))[order]
        v_inst = np.maximum(0.0, at_instances) if s.v_inst is None else s.v_inst
        out.append(_Samples(s.t_inst, v_inst, t_grid[order], v_grid, s.exact))
    return out


def _relation_samplings(scene, constraint, kept: dict) -> list[_Sampling]:
    out = []
    for rel in constraint.relations:
        def score(shared, part, values=scene.evaluator(rel.expr, kept, constraint.span), kind=rel.kind):
            v = _score(values.at(shared, part), kind, constraint.weight)
            if constraint.when is not None:   # a conditional constraint counts only where it applies
                v = np.where(condition_holds(scene, constraint.when, shared.times[part]), v, -np.inf)
            return v

        t_inst, t_base, exact = _relation_times(scene, constraint, rel, kept)
        out.append(_Sampling(score, t_inst, t_base, exact))
    return out


def _relation_times(scene, constraint, rel, kept: dict) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """A relation's instances, its grid (None for a constraint ``@ t``) and whether its instances
    make it exact, from ``kept`` (instances.kept_times) when an earlier check of a scene of the
    same structure worked them out (a quarter of the check: acrobat 4.5 of 18 ms)."""
    t_inst = relation_instances(scene, constraint, rel, kept)
    if constraint.at is not None:
        return t_inst, None, False
    key = ("grid", rel.expr, rel.kind, constraint.name, constraint.interval, constraint.samples,
           scene.extra_instances.get(constraint.name))
    found = kept.get(key)
    if found is None:
        exact = constraint.samples is None and \
            exact_degree(scene, rel.expr, rel.kind, constraint.interval) is not None
        t_base = dense_times(scene, [rel.expr], *constraint.interval, t_inst)
        t_base.flags.writeable = False   # shared by the checks to come
        found = kept[key] = t_base, exact
    return (t_inst, *found)


def _bound_samplings(scene, dof, kept: dict) -> list[_Sampling | _Samples]:
    """A bound's instances are the control points (see instances.bound_times): their violation is
    the control points' own; the dense grid checks the curve, which they bound everywhere.

    A bound that every control point keeps is not sampled: the curve is a convex combination of
    its control points (B-splines are >= 0 and sum to 1), so it keeps the bound exactly, at
    every t, and the grid could only find rounding (this was most of the check's time on the
    arm's three bounded joints). A control point past the bound sends the curve to the grid,
    which tells where the curve itself is worst."""
    x, coef = dof_symbol(dof.name), np.asarray(dof.curve.coef, float)
    t_inst = bound_times(scene, dof.name)
    t_base = None
    out = []
    for bound, expr, at_points in ((dof.lo, x - (dof.lo or 0), coef - (dof.lo or 0)),
                                   (dof.hi, (dof.hi or 0) - x, (dof.hi or 0) - coef)):
        if bound is None:
            continue
        v_inst = np.maximum(0.0, -at_points)
        if not v_inst.any():
            out.append(_Samples(t_inst, v_inst, t_inst, v_inst, exact=True))
            continue
        if t_base is None:
            t_base = dense_times(scene, [x], scene.t0, scene.t1,
                                 np.union1d(t_inst, bound_extra_times(scene, dof.name)))

        def score(shared, part, values=scene.evaluator(expr, kept)):
            return _score(values.at(shared, part), TermKind.GE, 1.0)
        out.append(_Sampling(score, t_inst, t_base, exact=True, v_inst=v_inst))
    return out


def _summarize(name: str, samples: list[_Samples], tol: float | None, bound: bool) -> ConstraintCheck:
    worst_inst = max((float(s.v_inst.max(initial=0.0)) for s in samples), default=0.0)
    worst_dense, worst_t = 0.0, None
    for s in samples:
        i = int(np.argmax(s.v_grid)) if s.v_grid.size else 0
        if s.v_grid.size and s.v_grid[i] > worst_dense:
            worst_dense, worst_t = float(s.v_grid[i]), float(s.t_grid[i])
    # A relation's dense figure holds its instances (points of the motion, on its grid up to a
    # nudge off a repeated knot). A bound's instances are control points, not points of the
    # motion: its dense figure is the curve's own worst, which the convex hull keeps below theirs.
    return ConstraintCheck(name, worst_inst, worst_dense if bound else max(worst_dense, worst_inst), worst_t, tol)


def _all_samples(scene):
    """(check name, its relations' samples, its own tolerance) for every constraint and every
    bounded DOF, all their samplings evaluated together (:func:`_sample`)."""
    kept = kept_times(scene)
    checks = [(c.name, _relation_samplings(scene, c, kept), c.dense_tol) for c in scene.constraints.values()]
    checks += [(f"{dof.name}.bounds", _bound_samplings(scene, dof, kept), None)
               for dof in scene.dofs.values() if dof.lo is not None or dof.hi is not None]
    pending = [p for _, parts, _ in checks for p in parts if isinstance(p, _Sampling)]
    done = iter(_sample(pending))
    return [(name, [next(done) if isinstance(p, _Sampling) else p for p in parts], tol)
            for name, parts, tol in checks]


def check_scene(scene) -> DenseReport:
    """Every constraint and every DOF bound (named ``X.bounds``) of ``scene``, checked densely over
    the whole animation.

    Raises:
        StwError: a constraint that no longer compiles (e.g. it names a deleted definition).
    """
    return survey_failures(scene, None)[0]


def survey_failures(scene, tol: float | None) -> tuple[DenseReport, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The dense check; where new instances would help (see :func:`_refinement`; nothing when
    ``tol`` is None); and where each check fails: the local maxima of its dense violation above
    its tolerance, as (time, violation) rows, on relations whose instances are not placed exactly
    (where adaptive refinement inserts knots; see stw_tui/sos/refinement.py)."""
    checks, wanted, failing = {}, {}, {}
    for name, samples, own_tol in _all_samples(scene):
        checks[name] = _summarize(name, samples, own_tol, bound=name.endswith(".bounds"))
        if tol is not None:
            limit = own_tol if own_tol is not None else tol
            found = _refinement(scene, samples, limit)
            if found.size:
                wanted[name] = found
            peaks = _failing_peaks(samples, limit)
            if peaks.shape[0]:
                failing[name] = peaks
    return DenseReport(checks), wanted, failing


def _failing_peaks(samples: list[_Samples], limit: float) -> np.ndarray:
    """The local maxima of one check's dense violation above ``limit``, as (time, violation)
    rows in time order, instances included; none on an instant or on exactly placed instances."""
    found = []
    for s in samples:
        v = s.v_grid
        if v.size < 3 or s.t_inst.size < 2 or s.exact:
            continue
        peak = (v > limit) & (v >= np.r_[-np.inf, v[:-1]]) & (v >= np.r_[v[1:], -np.inf])
        found.append(np.column_stack([s.t_grid[peak], v[peak]]))
    found = np.concatenate(found) if found else np.zeros((0, 2))
    return found[np.argsort(found[:, 0], kind="stable")]


def _snap(scene, t: float) -> float:
    """Round a new instance time to 1/SNAP of the animation: the same instances for motions that
    differ only by rounding (two backends, two machines), so their re-solves stay comparable."""
    step = (scene.t1 - scene.t0) / SNAP
    return float(min(scene.t1, max(scene.t0, scene.t0 + round((t - scene.t0) / step) * step)))


def _refinement(scene, samples: list[_Samples], limit: float) -> np.ndarray:
    """Where new instances would help one check: the local maxima of its dense violation above
    ``limit`` that are not instances already (at most one per gap between instances)."""
    found = []
    for s in samples:
        v = s.v_grid
        if v.size < 3 or s.t_inst.size < 2 or s.exact:
            continue   # an instant, or exactly placed instances: more would add nothing
        peak = (v > limit) & (v >= np.roll(v, 1)) & (v >= np.roll(v, -1))
        peak[0] = peak[-1] = False
        gap = np.searchsorted(s.t_inst, s.t_grid)
        for g in np.unique(gap[peak]):   # the worst peak of each gap between instances
            in_gap = np.flatnonzero(peak & (gap == g))
            t = _snap(scene, s.t_grid[in_gap[np.argmax(v[in_gap])]])
            if np.min(np.abs(s.t_inst - t)) > 1e-9 * (scene.t1 - scene.t0):
                found.append(t)
    return np.unique(found) if found else np.zeros(0)   # (most checks: nothing, without unique's cost)
