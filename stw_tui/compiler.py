"""Symbolic compiler: sympy expression -> vectorized numeric value, gradient and Hessian.

"Symbolic once, numeric many": a term is differentiated with respect to the DOF symbols it uses
(value, velocity, acceleration of each DOF), common subexpressions are shared, and the result is
compiled once into a function evaluated over all instances at once. Differentiation and code
generation use symengine (hundreds of times faster than sympy on equations of motion); the sympy
expression is kept for backends that lower it themselves (torch).

Constants stay symbols: their values are runtime parameters, so changing one never recompiles.
Compiled terms are cached by (expression, parameter names).
"""

from __future__ import annotations

import hashlib
import os
import pickle
import threading
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import symengine as se
import sympy as sp

from . import limits
from .errors import LimitError, StwError
from .symbols import TIME, split_dof_symbol

_CACHE: dict[tuple, "CompiledTerm"] = {}
_CACHE_LOCK = threading.Lock()


_KINKS = (sp.Abs, sp.sign, sp.Max, sp.Min)


def _to_symengine(expr: sp.Basic):
    """Convert our own sympy expression (never user text) to symengine.

    symengine cannot differentiate abs, sign, min and max but can differentiate Piecewise, so
    those become Piecewise — built in symengine, because sympy folds nested Piecewise
    conditions into ITE objects symengine cannot read.
    """
    if not expr.has(*_KINKS):
        return se.S(expr)
    args = [_to_symengine(a) for a in expr.args]
    if isinstance(expr, sp.Abs):
        return se.Piecewise((args[0], args[0] >= 0), (-args[0], True))
    if isinstance(expr, sp.sign):
        return se.Piecewise((1, args[0] > 0), (-1, args[0] < 0), (0, True))
    if isinstance(expr, (sp.Max, sp.Min)):
        result = args[0]
        for arg in args[1:]:
            keep = result >= arg if isinstance(expr, sp.Max) else result <= arg
            result = se.Piecewise((result, keep), (arg, True))
        return result
    if isinstance(expr, sp.Add):
        return sum(args[1:], args[0])
    if isinstance(expr, sp.Mul):
        out = args[0]
        for a in args[1:]:
            out = out * a
        return out
    if isinstance(expr, sp.Pow):
        return args[0] ** args[1]
    return getattr(se, expr.func.__name__)(*args)  # sin, cos, atan2, exp, log, …


def _lambdify(args, outputs):
    """Compile with LLVM when the symengine build has it, else the portable lambda backend."""
    try:
        return se.Lambdify(args, outputs, cse=True, backend="llvm")
    except (RuntimeError, ValueError, TypeError):  # symengine built without LLVM
        return se.Lambdify(args, outputs, cse=True, backend="lambda")


@dataclass(frozen=True)
class LocalVar:
    """One DOF quantity a term depends on: DOF ``dof`` differentiated ``order`` times."""

    dof: str
    order: int

    @property
    def label(self) -> str:
        return self.dof + "'" * self.order


@dataclass(eq=False)
class CompiledTerm:
    """A scalar expression compiled for vectorized evaluation with its first and second derivatives.

    Attributes:
        expr: the fully substituted sympy expression (DOF symbols, ``t``, constants only).
        variables: the DOF quantities it depends on, in a fixed order (the gradient's columns).
        parameters: the names of the constants it uses, in the order values are passed.
        hessian_pairs: (a, b) index pairs, a <= b, of structurally nonzero second derivatives.
    """

    expr: sp.Expr
    variables: tuple[LocalVar, ...]
    parameters: tuple[str, ...]
    hessian_pairs: tuple[tuple[int, int], ...] = field(default=())
    _value_fn: object = field(default=None, repr=False)
    _full_fn: object = field(default=None, repr=False)

    @property
    def k(self) -> int:
        return len(self.variables)

    @cached_property
    def dofs(self) -> frozenset[str]:
        return frozenset(v.dof for v in self.variables)

    def _inputs(self, values: np.ndarray, times: np.ndarray, params: np.ndarray) -> np.ndarray:
        n = len(times)
        columns = [np.asarray(values, dtype=float).reshape(n, self.k), np.asarray(times, float)[:, None]]
        if len(params):
            columns.append(np.broadcast_to(np.asarray(params, float), (n, len(params))))
        return np.ascontiguousarray(np.hstack(columns))

    def value(self, values: np.ndarray, times: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Term values at n instances.

        Args:
            values: (n, k) values of ``variables`` at each instance.
            times: (n,) instance times.
            params: values of ``parameters``.
        Returns:
            (n,) array.
        """
        n = len(times)
        if n == 0:
            return np.zeros(0)
        out = np.asarray(self._value_fn(self._inputs(values, times, params)), dtype=float)
        return out.reshape(n)

    def full(self, values, times, params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Values (n,), gradient (n, k) and Hessian entries (n, len(hessian_pairs))."""
        n = len(times)
        nh = len(self.hessian_pairs)
        if n == 0:
            return np.zeros(0), np.zeros((0, self.k)), np.zeros((0, nh))
        out = np.asarray(self._full_fn(self._inputs(values, times, params)), dtype=float)
        out = out.reshape(n, 1 + self.k + nh)
        return out[:, 0], out[:, 1:1 + self.k], out[:, 1 + self.k:]


def compile_term(expr: sp.Expr, dof_names: frozenset[str] | set[str],
                 constant_names: frozenset[str] | set[str]) -> CompiledTerm:
    """Compile a fully substituted expression (cached by expression).

    Args:
        expr: sympy expression in DOF symbols, ``t`` and constant symbols only.
        dof_names: names of all DOF (to tell a DOF value symbol from a constant).
        constant_names: names of all constants.
    Raises:
        StwError: if the expression contains a symbol that is neither (a missing definition).
    """
    if isinstance(expr, (int, float)):
        expr = sp.Float(expr)
    check_size(expr)
    symbols = expr.free_symbols
    variables, parameters = [], []
    for symbol in symbols:
        if symbol == TIME:
            continue
        name, order = split_dof_symbol(symbol)
        if name in dof_names:
            variables.append(LocalVar(name, order))
        elif order == 0 and name in constant_names:
            parameters.append(name)
        else:
            raise StwError(f"'{symbol.name}' is not defined (deleted or renamed?)")
    variables = tuple(sorted(variables, key=lambda v: (v.dof, v.order)))
    parameters = tuple(sorted(parameters))
    key = (expr, variables, parameters)
    with _CACHE_LOCK:
        cached = _CACHE.get(key)
    if cached is not None:
        return cached
    term = _build(expr, variables, parameters)
    with _CACHE_LOCK:
        _CACHE[key] = term
    return term


def check_size(expr: sp.Basic) -> None:
    """Refuse, before any work on it, an expression too large to compile in reasonable time, or
    with an integer exponent that compiled code would wrap (x^2147483648 evaluates to inf).

    The size is that of the expression as a tree (what differentiation and code generation
    walk), counted over its distinct nodes only, so a subexpression shared 2^30 times costs one
    visit.

    Raises:
        StwError: naming the limit expression_size or exponent.
    """
    most, largest_exponent = limits.value("expression_size"), limits.value("exponent")
    sizes: dict[sp.Basic, int] = {}
    stack = [expr]
    while stack:   # iterative post-order: deep expressions must not exhaust the Python stack
        node = stack[-1]
        pending = [a for a in node.args if a not in sizes]
        if pending:
            stack.extend(pending)
            continue
        stack.pop()
        if node in sizes:
            continue
        if node.is_Pow and node.exp.is_Integer and abs(node.exp) > largest_exponent:
            raise LimitError(limits.over("exponent", node.exp, f"{_clip(node)}: exponent") +
                             "; compiled code cannot raise to such a power exactly")
        sizes[node] = 1 + sum(sizes[a] for a in node.args)
        if sizes[node] > most:
            raise LimitError(limits.over("expression_size", f"{sizes[node]}+ nodes",
                                         "an expression (its subexpressions substituted) of") +
                             "; a long linkage's forces grow fast")


_HUGE = 10**18   # sizes are capped here: only "over the limit" matters


def _tree_size(expr: sp.Basic, leaf_size) -> int:
    """Size of ``expr`` as a tree, ``leaf_size(symbol)`` counting for each symbol, computed over
    its distinct nodes (iteratively: deep expressions must not exhaust the Python stack)."""
    sizes: dict[sp.Basic, int] = {}
    stack = [expr]
    while stack:
        node = stack[-1]
        pending = [a for a in node.args if a not in sizes]
        if pending:
            stack.extend(pending)
            continue
        stack.pop()
        if node not in sizes:
            own = leaf_size(node) if node.is_Symbol else 1
            sizes[node] = min(_HUGE, own + sum(sizes[a] for a in node.args))
    return sizes[expr]


def expanded_size(expr: sp.Basic, definitions: dict[sp.Symbol, sp.Basic]) -> int:
    """The tree size ``expr`` will have once every defined symbol in it is replaced by its
    definition, recursively — computed without substituting anything, so a chain of
    subexpressions each using the previous twice (2^30 nodes after 30 lines) is measured at once.
    A primed subexpression (its time derivative) counts four times per prime."""
    named = {s.name: d for s, d in definitions.items()}
    known: dict[str, int] = {}

    def base_of(symbol) -> str | None:
        base = symbol.name.rstrip("'")
        return base if base in named else None

    def used(e) -> set[str]:
        seen, stack, names = set(), [e], set()
        while stack:
            node = stack.pop()
            if node in seen:
                continue
            seen.add(node)
            if node.is_Symbol and base_of(node) is not None:
                names.add(base_of(node))
            stack.extend(node.args)
        return names

    def leaf(symbol) -> int:
        base = base_of(symbol)
        if base is None:
            return 1
        primes = len(symbol.name) - len(base)
        return min(_HUGE, known.get(base, 1) * 4 ** primes)

    todo, visiting = list(used(expr)), set()
    while todo:   # sizes of the definitions, dependencies first (a circle counts 1; expand reports it)
        name = todo[-1]
        if name in known:
            todo.pop()
            continue
        waiting = [n for n in used(named[name]) if n not in known and n not in visiting]
        if waiting and name not in visiting:
            visiting.add(name)
            todo.extend(waiting)
            continue
        todo.pop()
        known[name] = _tree_size(named[name], leaf)
    return _tree_size(expr, leaf)


def _clip(power: sp.Pow) -> str:
    return f"{power.base}^{power.exp}" if power.base.is_Symbol else f"a power ^{power.exp}"


def _symbol_of(var: LocalVar) -> se.Symbol:
    return se.Symbol(var.label)


def _disk_cache_path(expr, variables, parameters) -> Path | None:
    """Where the compiled functions of a term are kept across runs (None: caching is off).

    ``STW_CACHE_DIR`` overrides the place (``off`` disables it); the key is the expression's
    text with its argument order and the symengine version, so a changed linkage or term
    compiles afresh. The files are pickles this program wrote itself, in the user's own cache.
    """
    root = os.environ.get("STW_CACHE_DIR") or str(Path.home() / ".cache" / "stw" / "terms")
    if root == "off":
        return None
    key = f"{se.__version__}|{_to_symengine(expr)}|{variables}|{parameters}"  # C++ printing: fast
    return Path(root) / (hashlib.sha256(key.encode()).hexdigest() + ".pkl")


def _build(expr: sp.Expr, variables: tuple[LocalVar, ...], parameters: tuple[str, ...]) -> CompiledTerm:
    path = _disk_cache_path(expr, variables, parameters)
    if path is not None and path.is_file():
        try:
            pairs, value_fn, full_fn = pickle.loads(path.read_bytes())
            return CompiledTerm(expr=expr, variables=variables, parameters=parameters,
                                hessian_pairs=tuple(pairs), _value_fn=value_fn, _full_fn=full_fn)
        except Exception:  # a stale or damaged cache entry: compile again
            pass
    term = _compile(expr, variables, parameters)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_bytes(pickle.dumps((term.hessian_pairs, term._value_fn, term._full_fn)))
            tmp.replace(path)   # atomic: concurrent runs never read half a file
        except (OSError, pickle.PicklingError, TypeError):
            pass  # caching is an optimization only
    return term


def _compile(expr: sp.Expr, variables: tuple[LocalVar, ...], parameters: tuple[str, ...]) -> CompiledTerm:
    e = _to_symengine(expr)
    var_syms = [_symbol_of(v) for v in variables]
    args = var_syms + [se.Symbol(TIME.name)] + [se.Symbol(p) for p in parameters]
    grad = [e.diff(v) for v in var_syms]
    pairs, hess = [], []
    for a, ga in enumerate(grad):
        if ga.is_zero or ga.is_number:
            continue
        for b in range(a, len(var_syms)):
            hab = ga.diff(var_syms[b])
            if not hab.is_zero:
                pairs.append((a, b))
                hess.append(hab)
    value_fn = _lambdify(args, [e])
    full_fn = _lambdify(args, [e, *grad, *hess])
    return CompiledTerm(expr=expr, variables=variables, parameters=parameters,
                        hessian_pairs=tuple(pairs), _value_fn=value_fn, _full_fn=full_fn)


def cache_size() -> int:
    """Number of compiled terms held (for tests and the status line)."""
    return len(_CACHE)
