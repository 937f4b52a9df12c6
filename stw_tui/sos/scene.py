"""The scene: everything a session has defined, as plain data.

A scene is changed only by the interpreter, one command at a time, on a copy that replaces the
original when the command succeeds — so a failed command leaves the scene exactly as it was.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, field, replace

import numpy as np
import sympy as sp

from stw_tui.sos.attachments import (added_terms, all_attachments, attached_dofs, pieces, replace_attached,
                                     restrict)
from stw_tui.sos.spline import DofCurve, SharedTimes
from stw_tui.sym.compiler import free_symbols, xreplace
from stw_tui.sym.errors import LimitError, StwError
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.symbols import dof_symbol, named_symbol

DEFAULT_SETTINGS: dict[str, float] = {
    "tol_violation": 1e-8,   # max |constraint| accepted as satisfied
    "tol_kkt": 1e-6,         # relative distance from a KKT point: sqrt(Newton decrement / max(1, |R|))
    "tol_step": 1e-10,       # relative step length counted as "no progress"
    "quadrature": 4,         # Gauss-Legendre points per knot span for objective integrals
    "merit": 1.0,            # least weight of constraint violation in the line-search merit
    "frame": 0.0,            # frame time shown by the player
    "dense_tol": 1e-6,       # max violation between instances (the continuous-time check)
    "adaptive": 1.0,         # 1: add instances where the continuous-time check fails, and re-solve
    "adaptive_rounds": 4,    # at most this many re-solves per `iterate`
    "adaptive_points": 2000,  # adaptive refinement inserts knots while the scene has at most this many control points
    "preview": 0.0,          # 1: a solve's result is a proposal to `accept` or `reject` (preview.py)
}


# Expansions by (expression, the definitions, DOF and limits they were made under), in
# least-recently-used order; shared by scene copies (each command works on a copy) and threads.
_EXPANDED: dict[tuple, sp.Basic] = {}
_EXPANDED_LOCK = threading.Lock()
_EXPANDED_SIZE = 2048


class ExpressionValues:
    """An expression's values on the scene's curves as they are now, as a function of the times
    (:meth:`Scene.evaluator`); or at part of a :class:`~stw_tui.sos.spline.SharedTimes`, whose
    curve values are shared with other expressions'."""

    def __init__(self, term, params: np.ndarray, curves: list[tuple[DofCurve, int]]):
        self.term, self.params, self.curves = term, params, curves

    def __call__(self, times) -> np.ndarray:
        return self.at(SharedTimes(times), slice(None))

    def at(self, shared: SharedTimes, part: slice) -> np.ndarray:
        """The values at ``shared.times[part]``: the same numbers as at those times alone."""
        times = shared.times[part]
        if not self.curves:
            return self.term.value(np.zeros((times.size, 0)), times, self.params)
        columns = [shared.values(curve, order, part) for curve, order in self.curves]   # (n, k)
        return self.term.value(np.column_stack(columns), times, self.params)


@dataclass
class Dof:
    """A degree of freedom: a cubic B-spline curve with optional bounds, damping and keys."""

    name: str
    curve: DofCurve
    lo: float | None = None
    hi: float | None = None
    damp: float = 0.0
    keys: list[tuple[float, float]] = field(default_factory=list)


@dataclass(frozen=True)
class Relation:
    """One relation of a constraint, normalized to ``expr = 0`` or ``expr >= 0``."""

    expr: sp.Expr
    kind: TermKind   # EQ or GE


@dataclass
class Constraint:
    """Relations imposed at an instant or over an interval, optionally only `when` it holds."""

    name: str
    relations: tuple[Relation, ...]
    at: float | None = None
    interval: tuple[float, float] | None = None
    when: sp.Basic | None = None
    weight: float = 1.0
    text: str = ""
    samples: int | None = None   # instances per animation span (None: the scene's)
    dense_tol: float | None = None   # largest violation between instances (None: the scene's)

    @property
    def span(self) -> tuple[float, float]:
        """The times it holds at: its interval, or (T, T) for an instant (Scene.expand's ``scope``)."""
        return (self.at, self.at) if self.at is not None else self.interval

    @property
    def scope_text(self) -> str:
        """Where the constraint holds, as typed: ``@ T`` or ``on [A, B]``."""
        return f"@ {self.at:g}" if self.at is not None else f"on [{self.interval[0]:g}, {self.interval[1]:g}]"


@dataclass
class Objective:
    """Expressions to minimize: squared, weighted and integrated over an interval (None: the span),
    or squared and weighted at one instant ``at`` (a terminal cost). ``sense`` "minimize" or
    "maximize": one expression taken as it is, signed, not squared (W e or -W e)."""

    name: str
    exprs: tuple[sp.Expr, ...]
    interval: tuple[float, float] | None = None
    weight: float = 1.0
    text: str = ""
    at: float | None = None
    sense: str | None = None


@dataclass
class Window:
    """A spacetime window: a subset of DOF (None: all) over a time interval (None: the span)."""

    name: str
    dofs: tuple[str, ...] | None = None
    interval: tuple[float, float] | None = None


def _real_value(expr: sp.Basic, values: dict, what: str) -> sp.Basic:
    """``expr`` with the constants' ``values`` put in, node by node, refused as not a real number
    where any node is not: sympy would fold abs(sqrt(-1.0)) to 1 and refuse min(sqrt(-1.0), 1) as
    not comparable (issue 54, item 9). atan2(0, 0) is 0, as in a literal and on the curves."""
    memo: dict = {}

    def walk(node):
        if node in values:
            return values[node]
        if not node.args:
            return node
        done = memo.get(node)
        if done is None:
            args = [walk(a) for a in node.args]
            if isinstance(node, sp.atan2) and all(a.is_zero for a in args):
                done = sp.Integer(0)
            else:
                try:
                    done = node.func(*args)
                except (TypeError, ValueError):   # Min and Max compare: a non-real one cannot
                    raise StwError(f"{what} is not a real number ({sp.sstr(node)[:60]})") from None
            if done.has(sp.I) or (done.is_number and done.is_extended_real is False):
                raise StwError(f"{what} is not a real number ({sp.sstr(node)[:60]})")
            memo[node] = done
        return done

    return walk(expr)


@dataclass
class Scene:
    """Everything a session has defined (DOF, constraints, objectives...) as plain data."""

    t0: float = 0.0
    t1: float = 1.0
    knots: int = 12
    samples: int | None = None   # constraint instances per animation span; default 2 * knots
    constants: dict[str, float] = field(default_factory=dict)
    dofs: dict[str, Dof] = field(default_factory=dict)
    lets: dict[str, sp.Expr] = field(default_factory=dict)
    derived: dict[str, sp.Expr] = field(default_factory=dict)   # from linkages, read-only names
    linkages: dict[str, object] = field(default_factory=dict)
    constraints: dict[str, Constraint] = field(default_factory=dict)
    objectives: dict[str, Objective] = field(default_factory=dict)
    windows: dict[str, Window] = field(default_factory=lambda: {"all": Window("all")})
    active_window: str = "all"
    backend: str = "scipy"
    backend_options: dict[str, str] = field(default_factory=dict)
    settings: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_SETTINGS))
    shake_count: int = 0
    # Instances added where the continuous-time check failed, by constraint name (or "X.bounds").
    extra_instances: dict[str, tuple[float, ...]] = field(default_factory=dict)
    # Motion verbs (`hold`, `ballistic`): the verb's line and the constraints/objectives it made.
    verbs: dict[str, tuple[str, tuple[str, ...]]] = field(default_factory=dict)
    # Limits changed with `set limit NAME VALUE` (see stw_tui.sym.limits; the others are the defaults).
    limits: dict[str, int] = field(default_factory=dict)
    # Where `survey` sends its starts: a Dask scheduler (tcp://HOST:PORT), or "" for this machine.
    scheduler: str = ""
    # What a verb attached (`hold`: the object is the hand's point, its mass a load), by verb group.
    attachments: dict[str, tuple] = field(default_factory=dict)

    def copy(self) -> "Scene":
        """A copy that commands may change freely. Sympy expressions, curves and linkage specs
        are immutable and shared; only the mutable records are copied (deepcopy of the derived
        equations of motion cost more than the commands themselves)."""
        new = copy.copy(self)
        new.constants = dict(self.constants)
        new.dofs = {k: replace(v, keys=list(v.keys)) for k, v in self.dofs.items()}
        new.lets, new.derived, new.linkages = dict(self.lets), dict(self.derived), dict(self.linkages)
        new.constraints = {k: replace(v) for k, v in self.constraints.items()}
        new.objectives = {k: replace(v) for k, v in self.objectives.items()}
        new.windows = {k: replace(v) for k, v in self.windows.items()}
        new.backend_options, new.settings = dict(self.backend_options), dict(self.settings)
        new.extra_instances = dict(self.extra_instances)
        new.verbs = dict(self.verbs)
        new.attachments = dict(self.attachments)
        new.limits = dict(self.limits)
        return new

    # --- names -------------------------------------------------------------------------------
    def kind_of(self, name: str) -> str | None:
        """'dof', 'const', 'let' (subexpressions and derived names) or None."""
        if name in self.dofs:
            return "dof"
        if name in self.constants:
            return "const"
        if name in self.lets or name in self.derived:
            return "let"
        return None

    @property
    def sample_count(self) -> int:
        """Constraint instances per animation span: ``samples``, or twice the knot spans."""
        return self.samples if self.samples is not None else 2 * self.knots

    @property
    def window(self) -> Window:
        """The active window, the one `iterate` optimizes."""
        return self.windows[self.active_window]

    # --- expressions -------------------------------------------------------------------------
    def expand(self, expr: sp.Basic, scope: tuple[float, float] | None = None) -> sp.Basic:
        """Substitute subexpressions (lets and derived quantities) until only DOF, t and constants
        remain. ``f'`` and ``f''`` of a subexpression ``f`` become its time derivatives. A DOF
        attached over part of the animation (a held object) reads as what it is attached to
        there, and a load adds to its generalized forces there (stw_tui.sos.attachments): as a
        Piecewise in time, folded to one side wherever ``scope`` (the times the expression is
        read at: an instant ``(T, T)`` or an interval) decides it.

        The same expression under the same definitions expands to the same result, so results
        are kept (:data:`_EXPANDED`): a window build asks for each relation's expansion three
        times, and every `iterate` builds its window anew (a linkage's were 0.3-0.6 s of each).
        """
        key = (expr, frozenset(self.derived.items()), frozenset(self.lets.items()),
               tuple(self.dofs), frozenset(self.limits.items()), tuple(self.attachments.items()), scope)
        with _EXPANDED_LOCK:
            found = _EXPANDED.pop(key, None)
            if found is not None:
                _EXPANDED[key] = found              # now the most recently used
                return found
        if scope is not None:
            result = restrict(self.expand(expr), *scope)
        else:
            result = replace_attached(self, self._expand(expr))
        with _EXPANDED_LOCK:
            _EXPANDED[key] = result
            while len(_EXPANDED) > _EXPANDED_SIZE:
                del _EXPANDED[next(iter(_EXPANDED))]
        return result

    def expand_unattached(self, expr: sp.Basic) -> sp.Basic:
        """:meth:`expand` with every DOF read as its own curve (loads are added as usual)."""
        return self._expand(expr)

    def _expand(self, expr: sp.Basic) -> sp.Basic:
        definitions = added_terms(self, {named_symbol(n): e for n, e in {**self.derived, **self.lets}.items()})
        self._check_size(expr, definitions)
        for _ in range(100):
            symbols = free_symbols(expr)   # kept: compile_term asks it of the result again
            inside = symbols & definitions.keys()
            primed = {s for s in symbols if s.name.endswith("'") and
                      named_symbol(s.name.rstrip("'")) in definitions}
            if not inside and not primed:
                return expr
            replacements = {s: definitions[s] for s in inside}
            for s in primed:
                base = s.name.rstrip("'")
                replacements[s] = self.time_derivative(self._expand(named_symbol(base)), base,
                                                       len(s.name) - len(base))
            expr = xreplace(expr, replacements)
        raise StwError("subexpressions refer to each other in a circle")

    def _check_size(self, expr: sp.Basic, definitions: dict) -> None:
        """Refuse an expansion over the limit expression_size before doing it (it would take
        time and memory exponential in a chain of subexpressions)."""
        from stw_tui.sym import limits
        from stw_tui.sym.compiler import expanded_size

        names = {d.name for d in definitions}
        if any(s.name.rstrip("'") in names for s in expr.free_symbols):
            size = expanded_size(expr, definitions)
            if size > limits.value("expression_size", self.limits):
                raise LimitError(limits.over("expression_size", f"{size} nodes",
                                             "an expression (its subexpressions substituted) of",
                                             self.limits))

    def time_derivative(self, expr: sp.Expr, name: str, order: int) -> sp.Expr:
        """d^order/dt^order of an expanded expression, by the chain rule through the DOF.

        Raises:
            StwError: it would need a DOF's third derivative (curves have two).
        """
        from stw_tui.sym.linkage.derivative import time_derivative

        for k in range(order):
            used = free_symbols(expr)              # a walk of the tree: once, not per DOF
            for dof in self.dofs:
                if dof_symbol(dof, 2) in used:
                    raise StwError(f"{name}{chr(39) * order} needs the third derivative of {dof}; "
                                   f"{name}{chr(39) * k} already uses {dof}''")
            expr = time_derivative(expr, self.dofs)
        return expr

    def constant_values(self, names) -> np.ndarray:
        """The values of the named constants, in the given order (a compiled term's parameters)."""
        return np.array([self.constants[n] for n in names], dtype=float)

    def numeric(self, expr: sp.Basic, what: str = "value") -> float:
        """Evaluate a constant expression (numbers and constants only) to a float."""
        expr = self.expand(expr)
        from stw_tui.sym.compiler import double_finite

        used = {s for s in expr.free_symbols if s.name in self.constants}   # a scene may hold thousands
        others = expr.free_symbols - used
        if others:
            names = ", ".join(sorted(s.name for s in others))
            raise StwError(f"{what} must be a number or constant expression, but it uses {names}")
        if not double_finite(expr, {s.name: self.constants[s.name] for s in used}):
            # before sympy evaluates anything: exp(exp(exp(T))) would compute digits for ever
            raise StwError(f"{what} is not a finite number (beyond what a double holds)")
        value = _real_value(expr, {s: sp.Float(self.constants[s.name]) for s in used}, what)
        try:
            result = float(value.evalf())
        except TypeError:   # log(T)^3.25 with T = 0.5: complex once the constant's value is known
            raise StwError(f"{what} is not a real number ({sp.sstr(value)[:60]})") from None
        if not np.isfinite(result):
            raise StwError(f"{what} is not a finite number ({result})")
        return result

    def names_used_by(self, name: str) -> list[str]:
        """Definitions that refer to ``name`` (to refuse deleting something in use)."""
        symbol = named_symbol(name)
        from stw_tui.sym.symbols import dof_symbols
        targets = {symbol, named_symbol(name + "'"), named_symbol(name + "''")} | \
            (set(dof_symbols(name)) if name in self.dofs else set())
        users = []
        for n, e in self.lets.items():
            if n != name and e.free_symbols & targets:
                users.append(n)
        for c in self.constraints.values():
            if any(r.expr.free_symbols & targets for r in c.relations) or (
                    c.when is not None and c.when.free_symbols & targets):
                users.append(c.name)
        for o in self.objectives.values():
            if any(e.free_symbols & targets for e in o.exprs):
                users.append(o.name)
        for w in self.windows.values():
            if w.dofs and name in w.dofs:
                users.append(w.name)
        return users

    def evaluate(self, expr: sp.Basic, times) -> np.ndarray:
        """Values of an expression (DOF and their derivatives, t, constants, subexpressions) on
        the scene's curves at ``times``: what `print`, the plots, figures and the dense check show.

        With attachments, each stretch between the times one starts or ends is read with its own
        term (each DOF one branch there, as the window reads it) and each such time alone: one
        term holding every branch of a Piecewise is far larger to compile (a planted second
        foot's joints are inverse kinematics over its stance).

        Raises:
            StwError: the expression names something the scene no longer defines.
        """
        parts = all_attachments(self)
        if not parts:
            return self.evaluator(expr)(times)
        times = np.asarray(times, dtype=float)
        flat = times.reshape(-1)
        out = np.empty(flat.shape)
        done = np.zeros(flat.shape, dtype=bool)
        stretches = pieces(self, self.t0, self.t1)
        for t in sorted({t for stretch in stretches for t in stretch}):
            at = flat == t
            if at.any():
                out[at], done[at] = self.evaluator(expr, scope=(t, t))(flat[at]), True
        for lo, hi in stretches:
            inside = (flat > lo) & (flat < hi)
            if inside.any():
                out[inside], done[inside] = self.evaluator(expr, scope=(lo, hi))(flat[inside]), True
        if not done.all():   # outside the animation's span
            out[~done] = self.evaluator(expr)(flat[~done])
        return out.reshape(times.shape)

    def evaluator(self, expr: sp.Basic, kept: dict | None = None,
                  scope: tuple[float, float] | None = None) -> ExpressionValues:
        """:meth:`evaluate` of one expression as a function of the times, for many calls on the
        curves as they are now: the expression is expanded and its compiled term found once (the
        dense check evaluates every relation seven times, and those lookups were a third of it).
        ``kept``: instances.kept_times of this scene, where the term is kept for the checks to
        come (it depends on the scene's structure only; finding it was half the pendulum's check).
        ``scope``: the times it is read at, as Scene.expand reads them (a constraint's own).

        Raises:
            StwError: the expression names something the scene no longer defines.
        """
        from stw_tui.sym.compiler import compile_term

        term = None if kept is None else kept.get(("term", expr, scope))
        if term is None:
            term = compile_term(self.expand(expr, scope), set(self.dofs), set(self.constants))
            if kept is not None:
                kept[("term", expr, scope)] = term
        return ExpressionValues(term, self.constant_values(term.parameters),
                                [(self.dofs[v.dof].curve, v.order) for v in term.variables])

    def dof_values(self, name: str, times, order: int = 0) -> np.ndarray:
        """DOF ``name`` (its ``order``-th time derivative) at ``times`` as the motion has it: its
        curve, except where it is attached (a held object is the hand's point there)."""
        if name in attached_dofs(self):
            return self.evaluate(dof_symbol(name, order), np.asarray(times, float))
        return self.dofs[name].curve.evaluate(times, order)

    # --- curves ------------------------------------------------------------------------------
    def coefficient_vector(self) -> np.ndarray:
        """All DOF control points as one vector, in DOF order (see :meth:`with_coefficients`)."""
        return np.concatenate([d.curve.coef for d in self.dofs.values()]) if self.dofs else np.zeros(0)

    def with_coefficients(self, vector: np.ndarray) -> None:
        """Replace all DOF control points from one concatenated vector (in DOF order)."""
        offset = 0
        for dof in self.dofs.values():
            n = dof.curve.n_coef
            dof.curve = dof.curve.with_coef(np.array(vector[offset:offset + n], dtype=float))
            offset += n
