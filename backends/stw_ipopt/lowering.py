"""A compiled term's sympy expression as a CasADi SX function.

Lowered node by node over the expression's distinct subtrees (shared subtrees stay shared in
the SX graph), iteratively, so a linkage's deep trees do not meet Python's recursion limit. Only
the functions the session language allows, and the Piecewise and relations stw itself builds
(attachments, ``when`` leaves), are lowered; anything else raises :class:`Unsupported` and the
backend solves that problem through stw's own numeric evaluations instead.

abs, sign, min and max become ``if_else`` exactly as the symbolic compiler lowers them to
Piecewise for symengine (stw_tui/sym/compiler.py): abs(u) is u where u >= 0, so its derivative
at 0 is 1 in both; sign passes a NaN on. A Piecewise without a true last branch is NaN outside
its pieces, as sympy's. ``if_else`` picks a branch without letting the other's NaN or infinity
through (CasADi's ``if_else_zero`` gives 0 for a false condition whatever the value).
"""

from __future__ import annotations

import math
import operator

import casadi
import sympy as sp

from stw_tui.sym.symbols import TIME


class Unsupported(Exception):
    """A node the lowering does not know (the backend then falls back to stw's evaluations)."""


_UNARY = {
    sp.sin: casadi.sin, sp.cos: casadi.cos, sp.tan: casadi.tan,
    sp.asin: casadi.asin, sp.acos: casadi.acos, sp.atan: casadi.atan,
    sp.sinh: casadi.sinh, sp.cosh: casadi.cosh, sp.tanh: casadi.tanh,
    sp.asinh: casadi.asinh, sp.acosh: casadi.acosh, sp.atanh: casadi.atanh,
    sp.exp: casadi.exp, sp.log: casadi.log,
}
_RELATIONS = {
    sp.StrictGreaterThan: operator.gt, sp.GreaterThan: operator.ge,
    sp.StrictLessThan: operator.lt, sp.LessThan: operator.le,
    sp.Equality: operator.eq, sp.Unequality: operator.ne,
}
_NUMBERS = {sp.pi: math.pi, sp.E: math.e, sp.nan: math.nan}


def _number(node: sp.Basic) -> float | None:
    """``node`` as a float when it is a real number, else None."""
    if node in _NUMBERS:
        return _NUMBERS[node]
    if node.is_Number:
        if node.is_infinite or node is sp.zoo:
            raise Unsupported(f"the number {node}")
        return float(node)
    return None


def _sign(u):
    return casadi.if_else(u > 0, 1.0, casadi.if_else(u < 0, -1.0, casadi.if_else(u == 0, 0.0, u)))


def _piecewise(pieces) -> object:
    """``(value, condition)`` pairs, first match wins; NaN where none holds."""
    out = math.nan
    for value, condition in reversed(pieces):
        out = value if condition is True else casadi.if_else(condition, value, out)
    return out


def _lower_node(node: sp.Basic, args: list):
    """One node, its arguments already lowered."""
    func = node.func
    if isinstance(node, sp.Add):
        out = args[0]
        for a in args[1:]:
            out = out + a
        return out
    if isinstance(node, sp.Mul):
        out = args[0]
        for a in args[1:]:
            out = out * a
        return out
    if isinstance(node, sp.Pow):
        base, exponent = args
        if node.exp == sp.Rational(1, 2):
            return casadi.sqrt(base)
        if node.exp == -1:
            return 1.0 / base
        return base ** exponent
    if func in _UNARY:
        if len(args) != 1:
            raise Unsupported(f"{func.__name__} of {len(args)} arguments")
        return _UNARY[func](args[0])
    if func is sp.atan2:
        return casadi.atan2(args[0], args[1])
    if func is sp.Abs:
        return casadi.if_else(args[0] >= 0, args[0], -args[0])
    if func is sp.sign:
        return _sign(args[0])
    if func in (sp.Max, sp.Min):
        out = args[0]
        for a in args[1:]:
            keep = out >= a if func is sp.Max else out <= a
            out = casadi.if_else(keep, out, a)
        return out
    if isinstance(node, sp.Piecewise):
        return _piecewise(list(zip(args[0::2], args[1::2])))
    if isinstance(node, tuple(_RELATIONS)):
        return _RELATIONS[type(node)](args[0], args[1])
    if isinstance(node, sp.And):
        return _fold(casadi.logic_and, args)
    if isinstance(node, sp.Or):
        return _fold(casadi.logic_or, args)
    if isinstance(node, sp.Not):
        return casadi.logic_not(args[0])
    raise Unsupported(f"'{func.__name__}'")


def _fold(op, args):
    out = args[0]
    for a in args[1:]:
        out = op(out, a)
    return out


def _children(node: sp.Basic) -> tuple:
    """The arguments lowered for ``node``: a Piecewise's (value, condition) pairs flattened."""
    if isinstance(node, sp.Piecewise):
        return tuple(part for pair in node.args for part in pair)
    return node.args


def lower(expr: sp.Basic, symbols: dict[str, object]):
    """``expr`` in CasADi, each free symbol replaced by ``symbols[name]``.

    Raises:
        Unsupported: a node or symbol the lowering does not know.
    """
    done: dict = {}
    stack = [expr]
    while stack:
        node = stack[-1]
        if node in done:
            stack.pop()
            continue
        if node is sp.true or node is sp.false:
            done[node] = node is sp.true
            stack.pop()
            continue
        if node.is_Symbol:
            if node.name not in symbols:
                raise Unsupported(f"the symbol '{node.name}'")
            done[node] = symbols[node.name]
            stack.pop()
            continue
        value = _number(node) if not node.args else None
        if value is not None:
            done[node] = value
            stack.pop()
            continue
        if not node.args:
            raise Unsupported(f"the atom {node!r}")
        waiting = [a for a in _children(node) if a not in done]
        if waiting:
            stack.extend(waiting)
            continue
        stack.pop()
        done[node] = _lower_node(node, [done[a] for a in _children(node)])
    out = done[expr]
    return out


def term_function(term) -> casadi.Function:
    """A compiled term as ``f(x, t, p) -> value``: ``x`` its variables (in ``term.variables``'
    order), ``t`` the time, ``p`` its parameters (in ``term.parameters``' order), all SX.

    Raises:
        Unsupported: as :func:`lower`.
    """
    x = casadi.SX.sym("x", term.k)
    t = casadi.SX.sym("t")
    p = casadi.SX.sym("p", len(term.parameters))
    symbols = {v.label: x[i] for i, v in enumerate(term.variables)}
    symbols[TIME.name] = t
    symbols.update({name: p[i] for i, name in enumerate(term.parameters)})
    value = lower(term.expr, symbols)
    if isinstance(value, bool):
        value = float(value)
    return casadi.Function("term", [x, t, p], [casadi.SX(value) if not isinstance(value, casadi.SX) else value])
