"""Attachments: a DOF that *is* an expression over part of the animation, and forces that act
only there.

A held ball is the hand's point while held. Tying two curves together by constraints holds only
at their instances (the hand is trigonometry of the joint curves, the ball a cubic spline), so
instead, while held, every expression reads the ball's DOF as the hand's coordinates and their
time derivatives: the ball is in the hand at every time by construction. Its own curve is used
outside the hold, and where it meets the hand (a catch, a release) constraints match position
and velocity at that instant. The held mass loads the holder's generalized forces over the same
interval (:class:`Attachment` with ``adds``).

Both become a sympy ``Piecewise`` in time when an expression is expanded
(:meth:`~stw_tui.sos.scene.Scene.expand`); :func:`restrict` folds it where a relation's scope
decides it, so that a flight relation after the release stays linear in the ball's curve (and
exact everywhere) and a relation inside the hold reads the hand alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import sympy as sp

from stw_tui.sym.compiler import free_symbols, xreplace
from stw_tui.sym.symbols import TIME, dof_symbols, named_symbol


@dataclass(frozen=True)
class Attachment:
    """``target`` is ``expr`` on the time interval from ``a`` to ``b`` (or, with ``adds``, the
    derived quantity ``target`` has ``expr`` added there).

    An end is open where the attached curve meets its own there (a catch at ``a``, a release at
    ``b``): at that instant the DOF's own curve is read, which the verb's constraints match to
    the expression in position and velocity. An end at the animation's start or end is closed.
    """

    target: str          # a DOF (replaced) or a derived name such as tau_ELBOW (added to)
    expr: sp.Expr        # in the scene's names (arm.tip.x), expanded on use
    a: float
    b: float
    closed_a: bool = False
    closed_b: bool = False
    adds: bool = False
    note: str = ""       # what `describe` says instead of the expression (a long one)

    @property
    def condition(self) -> sp.Basic:
        """Where it applies, as a condition on the time symbol."""
        lower = (TIME >= self.a) if self.closed_a else (TIME > self.a)
        upper = (TIME <= self.b) if self.closed_b else (TIME < self.b)
        return sp.And(lower, upper)

    def describe(self) -> str:
        """What it does, as `hold` and `show` print it: ``BX is arm.tip.x on [0, 0.55]``."""
        what = self.note or f"{self.target} is {sp.sstr(self.expr)}"
        return f"{what} on [{self.a:g}, {self.b:g}]"


def all_attachments(scene) -> tuple[Attachment, ...]:
    """Every attachment of the scene, in the order the verbs made them."""
    return tuple(part for parts in scene.attachments.values() for part in parts)


def attached_dofs(scene) -> frozenset[str]:
    """The DOF that some attachment replaces over part of the animation."""
    return frozenset(p.target for p in all_attachments(scene) if not p.adds)


def added_terms(scene, definitions: dict) -> dict:
    """``definitions`` (symbol -> expression) with each load added where it acts."""
    out = dict(definitions)
    for part in all_attachments(scene):
        if part.adds:
            symbol = named_symbol(part.target)
            out[symbol] = out[symbol] + _load(part)
    return out


@lru_cache(maxsize=256)
def _load(part: Attachment) -> sp.Piecewise:
    """A load as a Piecewise in time: made once (sympy's Piecewise checks its conditions as it
    is built, half of an arm's expansions when it was made at each)."""
    return sp.Piecewise((part.expr, part.condition), (0, True))


def pieces(scene, a: float, b: float) -> list[tuple[float, float]]:
    """[a, b] cut where an attachment starts or ends: an objective is integrated piece by piece
    (a held ball's mass loads the torques only while held), each piece's term read there alone,
    one branch of the Piecewise instead of both, its quadrature not straddling the jump."""
    cuts = sorted({a, b, *(t for p in all_attachments(scene) for t in (p.a, p.b) if a < t < b)})
    return list(zip(cuts[:-1], cuts[1:]))


def replace_attached(scene, expr: sp.Basic) -> sp.Basic:
    """``expr`` (expanded: DOF, t and constants) with each attached DOF, and its first and second
    derivatives, read as the attachment's expression where it applies."""
    replaced = [p for p in all_attachments(scene) if not p.adds]
    if not replaced:
        return expr
    used = free_symbols(expr)
    replacements = {}
    for dof in {p.target for p in replaced}:
        parts = [p for p in replaced if p.target == dof]
        for order, symbol in enumerate(dof_symbols(dof)):
            if symbol not in used:
                continue
            pieces = [(_held(scene, p.expr, order), p.condition) for p in parts]
            replacements[symbol] = sp.Piecewise(*pieces, (symbol, True))
    return xreplace(expr, replacements) if replacements else expr


def _held(scene, expr: sp.Expr, order: int) -> sp.Expr:
    """The attachment's expression (expanded) differentiated ``order`` times in time.

    Differentiated before the DOF it reads are themselves read as their attachments (a second
    foot's joints follow the hip, whose base hangs from the first foot): the derivatives of the
    plain expression go through symengine, and the attached DOF's derivatives are then read as
    theirs, which the chain rule makes the same (those of a Piecewise went through sympy, 5 s of
    a hip's second derivative)."""
    expanded = scene.expand_unattached(expr)
    if order:
        expanded = scene.time_derivative(expanded, str(expr), order)
    return replace_attached(scene, expanded)


def restrict(expr: sp.Basic, lo: float, hi: float) -> sp.Basic:
    """``expr`` read on the times from ``lo`` to ``hi`` only: each Piecewise in time whose choice
    is the same at every time there becomes that choice.

    An interval is read on its inside (lo, hi): a relation over an interval is about what
    happens there, and its instances at the ends are limits from inside (a contact's push over
    its stance [A, B] is the stance's force at A and B too, not the flight's beside it). An
    instant (lo == hi) is read at that time: a release at B reads the object's own curve."""
    if not expr.has(sp.Piecewise):
        return expr

    memo: dict = {}     # a shared subtree (the hand's terms) is folded once

    def fold(node):
        if not node.args:
            return node
        done = memo.get(node)
        if done is None:
            done = memo[node] = _fold(node)
        return done

    def _fold(node):
        if isinstance(node, sp.Piecewise):
            kept = []
            for value, cond in node.args:
                decided = _decide(cond, lo, hi)
                if decided is False:
                    continue
                if decided is True and not kept:
                    return fold(value)
                kept.append((fold(value), cond))
                if decided is True:
                    break
            return sp.Piecewise(*kept) if kept else sp.nan
        args = [fold(a) for a in node.args]
        if all(a is b for a, b in zip(args, node.args)):
            return node
        return node.func(*args)

    return fold(expr)


def _decide(cond, lo: float, hi: float) -> bool | None:
    """Whether a condition on time holds at every time of [lo, hi] (True), at none (False), or
    differs (None; also for conditions on anything but time)."""
    if cond is sp.true or cond is True:
        return True
    if cond is sp.false or cond is False:
        return False
    if isinstance(cond, sp.And):
        parts = [_decide(c, lo, hi) for c in cond.args]
        return False if False in parts else True if all(p is True for p in parts) else None
    if isinstance(cond, sp.Or):
        parts = [_decide(c, lo, hi) for c in cond.args]
        return True if True in parts else False if all(p is False for p in parts) else None
    if not isinstance(cond, sp.core.relational.Relational):
        return None
    lhs, rhs, op = cond.lhs, cond.rhs, cond.rel_op
    if rhs == TIME and lhs.is_number:      # c < t is t > c
        lhs, rhs, op = rhs, lhs, {"<": ">", "<=": ">=", ">": "<", ">=": "<="}.get(op, op)
    if lhs != TIME or not rhs.is_number:
        return None
    c = float(rhs)
    if lo == hi:     # an instant: the condition at that time
        holds = {">": lo > c, ">=": lo >= c, "<": lo < c, "<=": lo <= c}.get(op)
        return holds
    # an interval: the condition on (lo, hi)
    if op in (">", ">="):
        return True if lo >= c else False if hi <= c else None
    if op in ("<", "<="):
        return True if hi <= c else False if lo >= c else None
    return None
