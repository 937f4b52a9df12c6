"""A sympy expression's text for the compiled terms' disk cache, read off the sympy tree itself.

The cache used to name a term by its symengine form's printed text: converting a linkage's
terms to symengine and printing them was a quarter of a cached compile of the arm (26 terms,
some 25 ms of 100), paid on every hit only to find the entry. This text is written from the
sympy tree in one walk over its distinct nodes, so a hit converts nothing.

What the text must do: two trees with one text must compile to the same code. The compiler
(compiler._to_symengine) puts every sum's and product's terms in sympy's sort order and converts
node by node, so the code is a function of the tree up to the order of those terms: here a sum's
and a product's terms are written sorted by their own texts, everything else in its order, each
leaf exactly (a Float by its mpmath value and precision, not its 15 printed digits), a node by
its class's name where that name is sympy's for it. A tree with a node this module does not
know (a Dummy, an undefined function) has no text (None), and the compiler names that term by
its symengine text as before.

:data:`REVISION` is part of every text: raise it when the conversion or the compiled code changes
for the same sympy tree (the symengine text changed with the conversion by itself).
"""

from __future__ import annotations

import hashlib
from functools import lru_cache

import sympy as sp
from sympy.functions.elementary.piecewise import ExprCondPair
from sympy.logic.boolalg import BooleanAtom

REVISION = 2
_LONG = 200       # characters: a longer node text is named by its digest
_COMMUTATIVE = (sp.Add, sp.Mul)
_NAMED_ATOMS = (sp.NumberSymbol, BooleanAtom, type(sp.I), type(sp.oo), type(sp.S.NegativeInfinity),
                type(sp.zoo), type(sp.nan))


@lru_cache(maxsize=None)
def _known(cls: type) -> bool:
    """Whether a compound node's class is sympy's own under its name (sin, Add, Piecewise, ...):
    its name then says which class it is."""
    return getattr(sp, cls.__name__, None) is cls or cls is ExprCondPair


def _leaf(node: sp.Basic) -> str | None:
    if isinstance(node, sp.Integer):
        return f"I{node.p}"
    if isinstance(node, sp.Rational):
        return f"Q{node.p}/{node.q}"
    if isinstance(node, sp.Float):
        return f"F{node._mpf_!r}:{node._prec}"
    if type(node) is sp.Symbol and node.is_commutative:   # not a Dummy (two may share a name),
        return f"S{node.name!r}"                          # nor one whose products keep order
    if isinstance(node, _NAMED_ATOMS):
        return type(node).__name__
    return None


def tree_text(expr: sp.Basic) -> str | None:
    """The text naming ``expr`` in the disk cache (see the module's docstring), or None when the
    tree holds a node this module does not know."""
    texts: dict[int, str] = {}     # by id: the nodes live as long as expr, and a Float's hash
    stack = [expr]                 # is not kept (sympy computes it at each call)
    while stack:
        node = stack[-1]
        if id(node) in texts:
            stack.pop()
            continue
        if not node.args:
            text = _leaf(node)
            if text is None:
                return None
            texts[id(node)] = text
            stack.pop()
            continue
        pending = [a for a in node.args if id(a) not in texts]
        if pending:
            stack.extend(pending)
            continue
        stack.pop()
        if not _known(type(node)):
            return None
        parts = [texts[id(a)] for a in node.args]
        if isinstance(node, _COMMUTATIVE):
            parts.sort()
        text = f"{type(node).__name__}({','.join(parts)})"
        # a long text by its digest: a text that held its subtrees' texts whole grew with the
        # tree, not with its distinct nodes (a planted leg's inverse kinematics, shared through
        # a linkage's equations, made keys of tens of megabytes)
        texts[id(node)] = text if len(text) <= _LONG else f"#{hashlib.blake2b(text.encode(), digest_size=20).hexdigest()}"
    return f"r{REVISION}|sympy {sp.__version__}|{texts[id(expr)]}"
