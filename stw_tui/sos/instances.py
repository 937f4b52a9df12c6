"""Where constraint instances go: the sample times at which a constraint is imposed.

One place decides this for every user: the window problem imposes constraints there, and the
continuous-time check (:mod:`stw_tui.sos.continuous`) reports the violation there beside the
violation between them.

- A constraint ``@ t`` has the one instance ``t``.
- A relation that is affine in DOF quantities with constant coefficients (``BY'' + g = 0``,
  ``X = 0``) is a piecewise polynomial in time of degree ``3 - r``, where ``r`` is the highest
  derivative it uses. It holds *exactly* everywhere on its interval when it holds at a set of
  points that determines such a piecewise polynomial (Schoenberg–Whitney): the knots, plus
  ``2 - r`` more points in the first and the last span. Inequalities of degree 1
  (``x'' >= -g``) hold between the knots when they hold at the knots. These relations get exactly
  those instances: fewer rows than uniform samples, and nothing for the optimizer to exploit.
- Every other relation gets the scene's uniform samples (or the constraint's ``samples=``), plus
  the instances that adaptive refinement added where the continuous-time check failed.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from functools import lru_cache

import numpy as np
import sympy as sp

from stw_tui.sym.compiler import compile_term, free_symbols
from stw_tui.sym.errors import StwError
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.symbols import TIME, dof_symbols

# Two times closer than this (relative to the span) are one instance.
_SAME_TIME = 1e-9


def uniform_times(scene, a: float, b: float, samples: int | None = None) -> np.ndarray:
    """Uniform samples on [a, b] at the scene's density (``samples`` per animation span)."""
    span = scene.t1 - scene.t0
    n = max(1, int(np.ceil((samples or scene.sample_count) * (b - a) / span - 1e-9)))
    return np.linspace(a, b, n + 1)


def exact_degree(scene, expr: sp.Expr, kind: str, scope: tuple[float, float] | None = None) -> int | None:
    """The highest DOF derivative ``r`` of a relation that instances can make hold exactly.

    Returns None when the relation is not affine in DOF quantities with constant coefficients
    (then no finite set of instances makes it exact), and None for inequalities of degree > 1 in
    time (holding at points does not bound a polynomial of degree 2 or 3 in between). ``scope``:
    the times the relation holds at (a held object's own curve is read outside its hold only).
    """
    return _exact_degree(scene.expand(expr, scope), frozenset(scene.dofs), kind, frozenset(scene.constants))


@lru_cache(maxsize=4096)
def _exact_degree(expr: sp.Expr, dof_names: frozenset[str], kind: str,
                  constant_names: frozenset[str]) -> int | None:
    free = free_symbols(expr)   # kept per expression: sympy walks the whole tree for each ask
    used = [(order, s) for name in dof_names for order, s in enumerate(dof_symbols(name)) if s in free]
    if not used or _curved(expr, dof_names, constant_names):
        return None
    symbols = {s for _, s in used}
    for _, s in used:   # the exact test, by sympy (cheap on what passes the screen: affine relations)
        coefficient = sp.diff(expr, s)
        if coefficient.free_symbols & (symbols | {TIME}):
            return None
    r = max(order for order, _ in used)
    rest = expr.xreplace({s: sp.Integer(0) for s in symbols})
    if TIME in rest.free_symbols:
        if not rest.is_polynomial(TIME) or sp.degree(rest, TIME) > 3 - r:
            return None
    if kind != TermKind.EQ and r < 2:
        return None
    return r


def _curved(expr: sp.Expr, dof_names: frozenset[str], constant_names: frozenset[str]) -> bool:
    """Whether ``expr`` has a second derivative in DOF quantities that is not identically zero,
    read off its compiled term (the window problem's own, kept in memory and on disk: symengine
    found the pairs when it was compiled). Such a relation is not affine, and sympy's derivatives
    of equations of motion, which would say so too, took half of luxo.stw's replay (0.5 of 1.0 s).
    False (or a term that does not compile) leaves the answer to the exact test."""
    try:
        return bool(compile_term(expr, dof_names, constant_names).hessian_pairs)
    except StwError:
        return False


def interval_cuts(breakpoints: np.ndarray, a: float, b: float) -> np.ndarray:
    """[a, b] cut at the breakpoints inside it. A breakpoint within rounding of an end (the knot
    0.49999999999999994 of 78 spans on [0, 3.9] against an interval ending at 0.5) is that end,
    not a piece of zero width."""
    slack = _SAME_TIME * max(b - a, 1.0)
    inside = breakpoints[(breakpoints > a + slack) & (breakpoints < b - slack)]
    return np.concatenate([[a], inside, [b]])


def exact_times(breakpoints: np.ndarray, a: float, b: float, r: int,
                repeated: np.ndarray | None = None) -> np.ndarray:
    """Points on [a, b] that determine a C^(2-r) piecewise polynomial of degree ``3 - r`` with
    these breakpoints (a space of dimension pieces + 3 - r): every breakpoint in [a, b] and its
    ends, plus ``2 - r`` interior points — the midpoints of the first and the last piece, or the
    thirds of a single piece."""
    cuts = interval_cuts(breakpoints, a, b)
    first, last = (cuts[0], cuts[1]), (cuts[-2], cuts[-1])
    if r == 2:
        extra = []
    elif r == 1:
        extra = [(first, 0.5)]
    elif cuts.size == 2:
        extra = [(first, 1 / 3), (first, 2 / 3)]
    else:
        extra = [(first, 0.5), (last, 0.5)]
    points = [lo + f * (hi - lo) for (lo, hi), f in extra]
    # A repeated knot inside (refine DOF @ T multiplicity=2) lowers the continuity there, which
    # frees the pieces on either side (one more dimension): their midpoints pin them down again.
    inside = [i for i in np.searchsorted(cuts, repeated if repeated is not None else ())
              if 0 < i < cuts.size - 1 and cuts[i] in repeated]
    beside = sorted({j for i in inside for j in (i - 1, i)})   # pieces, by their left cut
    points += [(cuts[j] + cuts[j + 1]) / 2 for j in beside]
    times = np.unique(np.concatenate([cuts, points]))
    if times.size < cuts.size + 2 - r + len(inside):
        # Midpoints shared (a piece between two repeated knots, or the first or last piece's own
        # midpoint): thirds of the pieces beside, so that the points still determine the space.
        times = np.unique(np.concatenate([times, [cuts[j] + f * (cuts[j + 1] - cuts[j])
                                                  for j in beside for f in (1 / 3, 2 / 3)]]))
    return times


def relation_times(scene, constraint, expr: sp.Expr, kind: str) -> np.ndarray:
    """The instance times of one relation of ``constraint`` over the whole animation."""
    if constraint.at is not None:
        return np.array([constraint.at])
    a, b = constraint.interval
    knots = [scene.dofs[name].curve.knots for name in dofs_used(scene, [expr], (a, b))]
    repeated = repeated_knots(knots)
    r = exact_degree(scene, expr, kind, (a, b)) if constraint.samples is None else None
    if r is not None:
        times = exact_times(np.unique(np.concatenate(knots)), a, b, r, repeated)
    else:
        times = merge_times(uniform_times(scene, a, b, constraint.samples),
                            extra_times(scene, constraint.name, a, b), scene.t1 - scene.t0)
    return on_own_side(times, a, b, repeated)


def relation_instances(scene, constraint, rel, kept: dict) -> np.ndarray:
    """:func:`relation_times` of one relation (read-only), from ``kept`` (:func:`kept_times`)
    when it was worked out before for a scene of the same structure: window builds and every
    check of the motion ask for them, and they stay while only the control points change
    (acrobat's window build: 4.0 -> 2.2 ms)."""
    key = ("instances", rel.expr, rel.kind, constraint.name, constraint.at, constraint.interval,
           constraint.samples, scene.extra_instances.get(constraint.name))
    found = kept.get(key)
    if found is None:
        found = relation_times(scene, constraint, rel.expr, rel.kind)
        found.flags.writeable = False   # shared by the builds and checks to come
        kept[key] = found
    return found


_KEPT_STRUCTURES = 4   # scene structures whose relations' times are kept (a session's few windows)
_KEPT: OrderedDict = OrderedDict()
_KEPT_LOCK = threading.Lock()


def structure_key(scene) -> tuple:
    """What every relation's instances and check grid depend on, besides its constraint's own
    scope and added instances: the span, the sampling density, every DOF's knots (in order), and
    the definitions and names that expand and classify expressions."""
    return (scene.t0, scene.t1, scene.sample_count,
            tuple((name, dof.curve.knots.tobytes()) for name, dof in scene.dofs.items()),
            frozenset(scene.lets.items()), frozenset(scene.derived.items()),
            frozenset(scene.limits.items()), frozenset(scene.constants), tuple(scene.attachments.items()))


def kept_times(scene) -> dict:
    """The times kept for scenes of this one's structure (:func:`structure_key`; each entry's
    key adds its constraint's scope and added instances): a dict that window builds and the
    continuous-time check fill. The last _KEPT_STRUCTURES structures are kept."""
    key = structure_key(scene)
    with _KEPT_LOCK:
        found = _KEPT.pop(key, None)
        if found is None:
            found = {}
            while len(_KEPT) >= _KEPT_STRUCTURES:
                _KEPT.popitem(last=False)
        _KEPT[key] = found
    return found


def dofs_used(scene, exprs, scope: tuple[float, float] | None = None) -> list[str]:
    """The DOF whose value, velocity or acceleration the expressions use (subexpressions expanded;
    read on ``scope``, when given, as Scene.expand reads it)."""
    symbols = set().union(*(free_symbols(scene.expand(e, scope)) for e in exprs))
    return [name for name in scene.dofs if set(dof_symbols(name)) & symbols]


def on_own_side(times: np.ndarray, a: float, b: float, repeated: np.ndarray) -> np.ndarray:
    """Curves are evaluated from the right at a knot. Where an interval [a, b] ends at a repeated
    knot (``repeated``; a take-off: `refine X @ T multiplicity=2`), its last instances must see the
    interval's own side, so they move to the float just before the knot; where it starts at one,
    its first instances move onto the knot. A knot within rounding of an end counts as that end
    (0.05 * 64 is 3.1999999999999997, not 3.2)."""
    if not repeated.size:
        return times
    scale = _SAME_TIME * max(abs(a), abs(b), 1.0)
    times = times.copy()
    at_end = repeated[np.abs(repeated - b) <= scale]
    if at_end.size:
        edge = min(float(at_end.min()), b)
        times[times >= edge] = np.nextafter(edge, -np.inf)
    at_start = repeated[np.abs(repeated - a) <= scale]
    if at_start.size:
        edge = max(float(at_start.max()), a)
        times[times <= edge] = edge
    return times


def repeated_knots(knot_vectors) -> np.ndarray:
    """Interior knots that appear more than once in any of the knot vectors."""
    found = [_repeated_in(np.asarray(knots, float).tobytes()) for knots in knot_vectors]
    return np.unique(np.concatenate(found)) if found else np.zeros(0)


@lru_cache(maxsize=256)   # a window build and a dense check ask for the same few vectors hundreds of times
def _repeated_in(knot_bytes: bytes) -> np.ndarray:
    knots = np.frombuffer(knot_bytes)
    inner = knots[(knots > knots[0]) & (knots < knots[-1])]
    values, counts = np.unique(inner, return_counts=True)
    repeated = values[counts > 1]
    repeated.flags.writeable = False   # shared by every caller
    return repeated


def bound_times(scene, dof_name: str) -> np.ndarray:
    """Where a DOF's bounds (lo=, hi=) are imposed: on its control points, named by the times they
    stand for (Greville abscissae). A cubic B-spline lies in the convex hull of its control points,
    so bounded control points bound the curve everywhere, not only at samples; it is stricter
    than the curve needs only where the curve turns just inside a bound. Instances added by hand
    (`instances X.bounds add T`) are the curve's values at those times (:func:`bound_extra_times`)."""
    return scene.dofs[dof_name].curve.greville()


def bound_extra_times(scene, dof_name: str) -> np.ndarray:
    """Times added to a DOF's bounds (by the continuous-time check or `instances X.bounds add`)."""
    return extra_times(scene, f"{dof_name}.bounds", scene.t0, scene.t1)


def extra_times(scene, key: str, a: float, b: float) -> np.ndarray:
    """The instances added for ``key`` (a constraint, or "X.bounds") that lie in [a, b]."""
    times = np.asarray(scene.extra_instances.get(key, ()), float)
    return times[(times >= a) & (times <= b)]


def merge_times(base: np.ndarray, extra: np.ndarray, span: float) -> np.ndarray:
    """Sorted union of two sets of times, with near-duplicates dropped."""
    times = np.sort(np.concatenate([base, extra]))
    if times.size < 2:
        return times
    keep = np.concatenate([[True], np.diff(times) > _SAME_TIME * span])
    return times[keep]
