"""Symbolic compiler: sympy expression -> vectorized numeric value, gradient and Hessian.

"Symbolic once, numeric many": a term is differentiated with respect to the DOF symbols it uses
(value, velocity, acceleration of each DOF), common subexpressions are shared, and the result is
compiled once into a function evaluated over all instances at once. Differentiation and code
generation use symengine (hundreds of times faster than sympy on equations of motion); the sympy
expression is kept for backends that lower it themselves (torch).

Constants stay symbols: their values are runtime parameters, so changing one never recompiles.
Compiled terms are cached by (expression, parameter names): in memory, the most recently used
``MAX_TERMS`` of them; on disk, in a cache directory that only the user can write, each entry
authenticated by an HMAC under the user's own key (see :func:`_cache_root`).
"""

from __future__ import annotations

import hashlib
import math
import hmac
import os
import pickle
import secrets
import stat
import threading
import warnings
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import symengine as se
import sympy as sp
from sympy.core.sorting import default_sort_key

from stw_tui.sym import limits
from stw_tui.sym.errors import LimitError, StwError
from stw_tui.sym.symbols import TIME, split_dof_symbol
from stw_tui.sym.tree_key import tree_text

MAX_TERMS = 256   # compiled terms kept in memory (each holds its machine code, up to ~1 MB)
_CACHE: dict[tuple, "CompiledTerm"] = {}   # in least-recently-used order
_CACHE_LOCK = threading.Lock()
_WARNED: set[str] = set()   # cache problems already reported (each once a process)




def _to_symengine(expr: sp.Basic):
    """Convert our own sympy expression (never user text) to symengine.

    The sums and products go over in a canonical order of their terms (:func:`_canonical`):
    symengine keeps them in the order given, and its compiled code adds and multiplies in that
    order.

    symengine cannot differentiate abs, sign, min and max but can differentiate Piecewise, so
    those become Piecewise — built in symengine, because sympy folds nested Piecewise
    conditions into ITE objects symengine cannot read.
    """
    return _convert(_canonical(expr, {}))


def sign_as_piecewise(e):
    """``e`` (symengine) with each sign(u) as the Piecewise :func:`_convert` makes of sympy's.
    symengine writes some expressions with a sign of its own (atan2(x, x) is
    pi/4 + pi/2 (sign(x) - 1)), whose derivative it leaves unevaluated and cannot compile.
    Called before differentiating, on a compile (the walk costs about a millisecond per
    thousand nodes)."""
    signs = e.atoms(se.sign)
    if not signs:
        return e
    return e.xreplace({s: _sign_piecewise(s.args[0]) for s in signs})


def _sign_piecewise(u):
    """sign(u) as a symengine Piecewise, which symengine can differentiate. Where u is not a real
    number (NaN: log of a negative) no comparison holds, and the last branch passes the NaN on
    (a final 0 made sign(log(-0.1)) read 0)."""
    return se.Piecewise((1, u > 0), (-1, u < 0), (0, se.Eq(u, 0)), (u, True))


def _canonical(expr: sp.Basic, memo: dict) -> sp.Basic:
    """``expr`` with the terms of every sum and product in sympy's default sort order.

    sympy's own order of a sum's terms can depend on the process's history (its caches): the
    arm tip's height in basketball.stw held two terms in swapped order after `stw bench` had
    compiled other sessions, which printed alike; symengine's code then summed them in the other
    order, a few functions differed in the last bit, and the solve took 95 iterations instead of
    120 to another local optimum. In this order the code is the same whatever came before.
    """
    if not expr.args:
        return expr
    done = memo.get(expr)
    if done is not None:
        return done
    args = [_canonical(a, memo) for a in expr.args]
    if isinstance(expr, (sp.Add, sp.Mul)):
        args.sort(key=default_sort_key)
        done = expr.func(*args, evaluate=False)
    elif any(a is not b for a, b in zip(args, expr.args)):
        done = expr.func(*args)
    else:
        done = expr
    memo[expr] = done
    return done


# sympy's relations and logic, as symengine builds them (Piecewise conditions, `when`)
_LOGIC = {sp.StrictLessThan: se.Lt, sp.LessThan: se.Le, sp.StrictGreaterThan: se.Gt,
          sp.GreaterThan: se.Ge, sp.Equality: se.Eq, sp.Unequality: se.Ne, sp.And: se.And,
          sp.Or: se.Or, sp.Not: se.Not}


def _convert(expr: sp.Basic, memo: dict | None = None):
    """:func:`_to_symengine` of an expression in canonical order, node by node, each distinct
    subtree once (``memo``). A linkage's equations of motion share their kinematics many times
    over: converting them as a tree (symengine's own sympify walks every path, and asking each
    node whether it holds an abs took as long again) cost 2.1 s for one of the jumper's contact
    rows, 23 s of its cold compile; this walk takes 1.5 ms and builds the same expression."""
    memo = {} if memo is None else memo
    done = memo.get(expr)
    if done is not None:
        return done
    if not expr.args:
        done = se.S(expr)
    elif isinstance(expr, sp.Piecewise):
        done = se.Piecewise(*[(_convert(e, memo), _convert(c, memo)) for e, c in expr.args])
    else:
        args = [_convert(a, memo) for a in expr.args]
        if isinstance(expr, sp.Abs):
            done = se.Piecewise((args[0], args[0] >= 0), (-args[0], True))
        elif isinstance(expr, sp.sign):
            done = _sign_piecewise(args[0])
        elif isinstance(expr, (sp.Max, sp.Min)):
            # where either is not a real number (NaN) neither comparison holds, and the sum
            # passes the NaN on (a final `arg` made min(sqrt(x), -x) read -x for x < 0)
            done = args[0]
            for arg in args[1:]:
                keep = done >= arg if isinstance(expr, sp.Max) else done <= arg
                take = done < arg if isinstance(expr, sp.Max) else done > arg
                done = se.Piecewise((done, keep), (arg, take), (done + arg, True))
        elif isinstance(expr, (sp.re, sp.conjugate)):
            # sympy writes abs(2^(T^x)) as 2^re(T^x); every value here is real (one that is not
            # is NaN, refused), so re(u) is u (symengine has no re: an internal error)
            done = args[0]
        elif isinstance(expr, sp.Heaviside):
            # the derivative of max(u, v), min and of a `when` (h' with let h = max(x, 0.1)):
            # symengine has none (an internal error); sympy's value at 0 is 1/2 unless given
            u, at_zero = args[0], (args[1] if len(args) > 1 else se.Rational(1, 2))
            done = se.Piecewise((1, u > 0), (0, u < 0), (at_zero, se.Eq(u, 0)), (u, True))
        elif isinstance(expr, sp.DiracDelta):
            # the derivative of sign(u): 0 off u = 0, infinite at it (1/u: refused there), NaN passes on
            u = args[0]
            done = se.Piecewise((0, u > 0), (0, u < 0), (1 / u, True))
        elif isinstance(expr, sp.im):   # abs((-2)^(T^x)) is 2^re(T^x)*exp(-pi*im(T^x)) in sympy
            raise StwError(f"not a real number: the value holds {sp.sstr(expr)[:60]}, the imaginary "
                           f"part of a power that is complex (a negative number to a varying power)")
        elif isinstance(expr, sp.Add):
            done = sum(args[1:], args[0])
        elif isinstance(expr, sp.Mul):
            done = args[0]
            for a in args[1:]:
                done = done * a
        elif isinstance(expr, sp.Pow):
            done = args[0] ** args[1]
        elif type(expr) in _LOGIC:
            done = _LOGIC[type(expr)](*args)
        else:
            done = getattr(se, expr.func.__name__)(*args)  # sin, cos, atan2, exp, log, …
            if isinstance(expr, sp.atan2) and not isinstance(done, se.atan2):
                # symengine writes atan2(u, u) as pi/4 + pi/2 (sign(u) - 1), which reads -pi/4
                # at u = 0 (and atan2(-u, u) +pi/4); atan2(0, 0) is 0 there as in C and mpmath
                zero = se.And(se.Eq(args[0], 0), se.Eq(args[1], 0))
                done = se.Piecewise((0, zero), (done, True))
    memo[expr] = done
    return done


def _complex(e) -> bool:
    """Whether the symengine expression holds a complex number: I (log(-2) = log(2) + I*pi) or a
    complex double (log(-0.75))."""
    e = se.S(e)
    return e.has(se.I) or any(n.is_real is False for n in e.atoms(se.Number))


def _lambdify(args, outputs):
    """Compile with LLVM when the symengine build has it, else the portable lambda backend."""
    try:
        return se.Lambdify(args, outputs, cse=True, backend="llvm")
    except (RuntimeError, ValueError, TypeError):  # symengine built without LLVM
        pass
    try:
        return se.Lambdify(args, outputs, cse=True, backend="lambda")
    except RuntimeError as exc:   # e.g. 0^x: its derivative holds log(0), a complex infinity
        if "infinity" in str(exc):
            raise StwError("the expression or one of its derivatives is infinite everywhere "
                           "(such as log(0) in the derivative of 0^x): rewrite it") from None
        if any(_complex(o) for o in outputs):   # (-2)^y: its derivative holds log(-2)
            raise StwError("the expression or one of its derivatives is not a real number (such as "
                           "log(-2) in the derivative of (-2)^x: a negative number to a varying "
                           "power)") from None
        raise


@dataclass(frozen=True)
class LocalVar:
    """One DOF quantity a term depends on: DOF ``dof`` differentiated ``order`` times."""

    dof: str
    order: int

    @property
    def label(self) -> str:
        """The quantity as the language writes it: ``x``, ``x'`` or ``x''``."""
        return self.dof + "'" * self.order


@dataclass(eq=False)
class CompiledTerm:
    """A scalar expression compiled for vectorized evaluation with its first and second derivatives.

    Attributes:
        expr: the fully substituted sympy expression (DOF symbols, ``t``, constants only).
        variables: the DOF quantities it depends on, in a fixed order (the gradient's columns).
        parameters: the names of the constants it uses, in the order values are passed.
        hessian_pairs: (a, b) index pairs, a <= b, of structurally nonzero second derivatives.
        affine: whether the value is ``Σ c_a(t) x_a + c_0(t)`` in its variables, found by
            symengine (its gradient free of them, and the value less the gradient's terms too):
            the gradient then depends on time and constants only. False where unproven.
    """

    expr: sp.Expr
    variables: tuple[LocalVar, ...]
    parameters: tuple[str, ...]
    hessian_pairs: tuple[tuple[int, int], ...] = field(default=())
    affine: bool = False
    _value_fn: object = field(default=None, repr=False)
    _full_fn: object = field(default=None, repr=False)
    # The text naming the term in the disk cache: a backend keeps what it derives from the term
    # under it too (cached_entry, store_entry); "" for a term not made by compile_term
    cache_key: str = field(default="", repr=False)

    @property
    def k(self) -> int:
        """The number of variables (the gradient's width)."""
        return len(self.variables)

    @cached_property
    def dofs(self) -> frozenset[str]:
        """The DOF the term depends on."""
        return frozenset(v.dof for v in self.variables)

    def _inputs(self, values: np.ndarray, times: np.ndarray, params: np.ndarray) -> np.ndarray:
        # [values | times | params] row by row, written into one array (np.hstack's conversions
        # cost more than the copies on the small groups of a window problem)
        n, k = len(times), self.k
        params = np.asarray(params, float).reshape(-1)
        out = np.empty((n, k + 1 + params.size))
        out[:, :k] = np.asarray(values, dtype=float).reshape(n, k)
        out[:, k] = times
        out[:, k + 1:] = params
        return out

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


@dataclass(eq=False)
class LiteralTerm(CompiledTerm):
    """A term whose decimal offset is a runtime parameter of a shared compiled skeleton.

    ``x = 0.25 @ 1`` and ``x = 0.75 @ 2`` compile once, as ``x + __lit0``: a session with many
    waypoints or keyframes compiles one term where it compiled one per number. ``expr``,
    ``variables``, ``parameters`` and ``hessian_pairs`` read as the term's own; ``core`` is the
    skeleton, called with the constants' values followed by ``literals``.
    """

    core: CompiledTerm | None = None
    literals: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def _with_literals(self, params) -> np.ndarray:
        return np.concatenate([np.asarray(params, float).reshape(-1), self.literals])

    def value(self, values: np.ndarray, times: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Term values at n instances (see :meth:`CompiledTerm.value`)."""
        return self.core.value(values, times, self._with_literals(params))

    def full(self, values, times, params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Values, gradient and Hessian entries (see :meth:`CompiledTerm.full`)."""
        return self.core.full(values, times, self._with_literals(params))


LITERAL = "__lit"   # placeholder names: the language refuses names with '__', so none collides


def lift_literals(expr: sp.Expr) -> tuple[sp.Expr, list[float]]:
    """``expr`` with its decimal offset made a placeholder symbol ``__lit0``, and that offset's
    value: ``x - 0.25`` becomes ``x + __lit0`` with [-0.25].

    Only the offset of a two-term sum is lifted, where waypoints and keyframes put their numbers:
    one addition, which IEEE arithmetic makes the same in either order, so a lifted term computes
    bitwise what the literal one did. Lifting more (coefficients, numbers inside sums of three or
    more terms) lets the compiler reorder the arithmetic, and those last-bit differences moved the
    bundled sessions' iterations (acrobat 48 -> 51 steps, objective by 7e-7 relative).
    """
    if not (isinstance(expr, sp.Add) and len(expr.args) == 2):
        return expr, []
    number, rest = expr.as_coeff_Add()
    if not isinstance(number, sp.Float):
        return expr, []
    return sp.Add(rest, sp.Symbol(f"{LITERAL}0", real=True)), [float(number)]


def compile_term(expr: sp.Expr, dof_names: frozenset[str] | set[str],
                 constant_names: frozenset[str] | set[str]) -> CompiledTerm:
    """Compile a fully substituted expression (cached by expression; terms that differ only in
    their decimal literals share one compiled skeleton, see :class:`LiteralTerm`).

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
    symbols = free_symbols(expr)
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
    term = _cached(key)
    if term is not None:
        return term
    skeleton, literals = lift_literals(expr)
    if literals:
        names = parameters + tuple(f"{LITERAL}{i}" for i in range(len(literals)))
        core_key = (skeleton, variables, names)
        core = _cached(core_key) or _remember(core_key, _build(skeleton, variables, names))
        term = LiteralTerm(expr=expr, variables=variables, parameters=parameters,
                           hessian_pairs=core.hessian_pairs, affine=core.affine, core=core,
                           literals=np.array(literals),
                           cache_key=f"{core.cache_key}|{literals!r}")
    else:
        term = _build(expr, variables, parameters)
    return _remember(key, term)


def _cached(key: tuple) -> CompiledTerm | None:
    """The compiled term under ``key``, now the most recently used; None when not cached."""
    with _CACHE_LOCK:
        cached = _CACHE.pop(key, None)
        if cached is not None:
            _CACHE[key] = cached
        return cached


def _remember(key: tuple, term: CompiledTerm) -> CompiledTerm:
    """Cache ``term`` under ``key``, dropping the least recently used beyond ``MAX_TERMS``."""
    with _CACHE_LOCK:
        _CACHE[key] = term
        while len(_CACHE) > MAX_TERMS:
            del _CACHE[next(iter(_CACHE))]
    return term


@lru_cache(maxsize=4096)
def free_symbols(expr: sp.Basic) -> frozenset:
    """``expr.free_symbols``, kept, and found visiting each distinct node once. sympy walks every
    path of the tree at every call, and a linkage's expressions share their kinematics many
    times over: the jumper's 131 walks took 8 s of its cold start."""
    found, seen, stack = set(), set(), [expr]
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if _own_free_symbols(type(node)):   # a Symbol, a number, or a class that binds some
            found |= node.free_symbols
        else:                               # sympy's own rule: the union over the arguments
            stack.extend(node.args)
    return frozenset(found)


@lru_cache(maxsize=None)
def _own_free_symbols(cls: type) -> bool:
    """Whether ``cls`` defines free_symbols otherwise than sympy's union over the arguments."""
    defined = next(k.__dict__["free_symbols"] for k in cls.__mro__ if "free_symbols" in k.__dict__)
    return defined is not sp.Basic.__dict__["free_symbols"]


def xreplace(expr: sp.Basic, rule: dict) -> sp.Basic:
    """``expr.xreplace(rule)``, each distinct node rebuilt once (sympy's walks every path of a
    shared tree: 8 s of the jumper's cold start, in replacing its feet's attached points)."""
    memo: dict[int, sp.Basic] = {}

    def walk(node):
        if node in rule:
            return rule[node]
        done = memo.get(id(node))
        if done is None and _own_xreplace(type(node)):   # a class with rules of its own
            done = memo[id(node)] = node.xreplace(rule)
        elif done is None:
            args = [walk(a) for a in node.args]
            changed = any(a is not b for a, b in zip(args, node.args))
            done = memo[id(node)] = node.func(*args) if changed else node
        return done

    return walk(expr)


@lru_cache(maxsize=None)
def _own_xreplace(cls: type) -> bool:
    """Whether ``cls`` replaces otherwise than sympy's rebuild from its replaced arguments."""
    defined = next(k.__dict__["_xreplace"] for k in cls.__mro__ if "_xreplace" in k.__dict__)
    return defined is not sp.Basic.__dict__["_xreplace"]


def check_size(expr: sp.Basic) -> None:
    """Refuse, before any work on it, an expression too large to compile in reasonable time, or
    with an integer exponent that compiled code would wrap (x^2147483648 evaluates to inf).

    The size is the number of its distinct nodes: what conversion, differentiation, common
    subexpressions and code generation each walk once (a linkage's equations with a planted
    leg's inverse kinematics in every link are millions of nodes as a tree, thousands distinct,
    and compile in seconds). Trees that subexpressions make exponential are refused before they
    are expanded (Scene.expand measures the substituted tree). An expression that passed under
    the same limits passes again without the walk.

    Raises:
        StwError: naming the limit expression_size or exponent.
    """
    _check_size(expr, limits.value_or_ceiling("expression_size"), limits.value_or_ceiling("exponent"))


@lru_cache(maxsize=4096)   # only passes are kept: lru_cache does not keep a raised error
def _check_size(expr: sp.Basic, most: int, largest_exponent: int) -> None:
    count = 0
    for node in _post_order(expr, atoms=False):   # a leaf counts 1 wherever it is
        if node.is_Pow and node.exp.is_Integer and abs(node.exp) > largest_exponent:
            raise LimitError(limits.over("exponent", node.exp, f"{_clip(node)}: exponent") +
                             "; compiled code cannot raise to such a power exactly")
        count += 1 + sum(1 for a in node.args if not a.args)
        if count > most:
            raise LimitError(limits.over("expression_size", f"{count}+ distinct nodes",
                                         "an expression (its subexpressions substituted) of") +
                             "; a long linkage's forces grow fast")


_HUGE = 10**18   # sizes are capped here: only "over the limit" matters


def _post_order(root, atoms: bool = True):
    """Each distinct node of an expression tree (sympy or symengine) once, its arguments before
    it; iteratively, so deep expressions do not exhaust the Python stack.

    ``atoms=False`` leaves out the leaves (no arguments) below the root: a walk that counts them
    where they occur needs no set of them, and hashing a sympy Float (not kept, unlike a compound
    node's hash) was a third of the size checks of a linkage's terms."""
    done: set = set()
    stack = [root]
    while stack:
        node = stack[-1]
        pending = [a for a in node.args if (atoms or a.args) and a not in done]
        if pending:
            stack.extend(pending)
            continue
        stack.pop()
        if node not in done:
            done.add(node)
            yield node


def _tree_size(expr: sp.Basic, leaf_size) -> int:
    """Size of ``expr`` as a tree, ``leaf_size(symbol)`` counting for each symbol, computed over
    its distinct nodes."""
    if not expr.args:
        return leaf_size(expr) if expr.is_Symbol else 1
    sizes: dict[sp.Basic, int] = {}
    for node in _post_order(expr, atoms=False):
        sizes[node] = min(_HUGE, 1 + sum(sizes[a] if a.args else leaf_size(a) if a.is_Symbol else 1
                                         for a in node.args))
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
            if not node.args:   # a leaf: no need to remember it (see _post_order)
                if node.is_Symbol and base_of(node) is not None:
                    names.add(base_of(node))
                continue
            if node in seen:
                continue
            seen.add(node)
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


def _warn_once(what: str, message: str) -> None:
    if what not in _WARNED:
        _WARNED.add(what)
        warnings.warn(message, RuntimeWarning, stacklevel=4)


def _private(path: Path, *, directory: bool) -> bool:
    """True when ``path`` is a real directory/file (not a link) owned by this user that no one
    else may write (a file: nor read)."""
    try:
        info = os.lstat(path)
    except OSError:
        return False
    kind_ok = stat.S_ISDIR(info.st_mode) if directory else stat.S_ISREG(info.st_mode)
    others = 0o022 if directory else 0o077
    return kind_ok and info.st_uid == os.getuid() and not info.st_mode & others


def _cache_root() -> tuple[Path, bytes] | None:
    """The disk cache directory and the user's key, or None when caching is off or unsafe.

    The place is ``$XDG_CACHE_HOME/stw/terms`` (``~/.cache/stw/terms`` without it);
    ``STW_CACHE_DIR`` overrides it (``off`` disables it). The cache is used only when the
    directory is owned by the user and not writable by group or others (a new one is created
    0700), and its entries are authenticated with HMAC-SHA256 under a per-user key kept in
    ``.key`` inside it (mode 0600, created on first use). An unsafe directory is reported once.

    A directory found safe is remembered with both files' inode, owner and mode (and the key's
    size and time): while those stay the same, its checks and the key's read are not repeated
    (they were 0.03 ms a term, 4% of the arm's cached compile); any change checks it afresh.
    """
    root = os.environ.get("STW_CACHE_DIR") or os.path.join(_user_cache(), "stw", "terms")
    if root == "off" or not hasattr(os, "getuid"):
        return None
    known = _SAFE_ROOTS.get(root)
    if known is not None and known[0] == _fingerprint(root):
        return known[1]
    found = _checked_root(Path(root))
    fingerprint = _fingerprint(root)
    if found is not None and fingerprint is not None:   # gone since the check: not remembered
        _SAFE_ROOTS[root] = (fingerprint, found)
    return found


def _user_cache() -> str:
    """XDG_CACHE_HOME when it is set to an absolute path (the XDG spec ignores a relative one),
    else ~/.cache."""
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    return xdg if os.path.isabs(xdg) else os.path.join(os.path.expanduser("~"), ".cache")


_SAFE_ROOTS: dict[str, tuple[tuple, tuple[Path, bytes]]] = {}   # root: (fingerprint, found)


def _fingerprint(root: str) -> tuple | None:
    """What a safe cache directory and its key file were: a change means checking them again."""
    try:
        folder, key = os.lstat(root), os.lstat(os.path.join(root, ".key"))
    except OSError:
        return None
    return (folder.st_ino, folder.st_uid, folder.st_mode,
            key.st_ino, key.st_uid, key.st_mode, key.st_size, key.st_mtime_ns)


def _checked_root(path: Path) -> tuple[Path, bytes] | None:
    """:func:`_cache_root`'s checks of ``path``, and the key read from it."""
    try:
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            path.mkdir(mode=0o700, exist_ok=True)
    except OSError:
        return None
    if not _private(path, directory=True):
        _warn_once(f"dir:{path}", f"stw: not using the term cache {path}: it is not a directory "
                                  "owned by you that only you can write; compiling afresh")
        return None
    key_path = path / ".key"
    try:
        fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as out:
            out.write(secrets.token_bytes(32))
    except FileExistsError:
        pass
    except OSError:
        return None
    if not _private(key_path, directory=False):
        _warn_once(f"key:{key_path}", f"stw: not using the term cache {path}: its key {key_path} "
                                      "is not a file of yours that only you can read")
        return None
    try:
        key = key_path.read_bytes()
    except OSError:
        return None
    return (path, key) if len(key) == 32 else None


def _term_key(e, variables, parameters) -> str:
    """A term's name in the disk cache: the expression's text with its argument order and the
    symengine version, so a changed linkage or term compiles afresh.

    symengine prints a double in 15 digits, so literals a few ulps apart (0.1 + 0.2 and 0.3)
    print alike: the text is followed by every literal's exact value, in the tree's own order,
    or two such terms would share one entry and compute with whichever literal came first.
    ``e`` is the term's expression in symengine (:func:`_to_symengine`)."""
    exact = ",".join(repr(float(node)) for node in _post_order(e) if isinstance(node, se.RealDouble))
    return f"{se.__version__}|{e}|{exact}|{variables}|{parameters}"  # C++ printing: fast


def _disk_cache_path(root: Path, key: str, kind: str = "") -> Path:
    """Where the entry ``key`` is kept: a compiled term's functions, or (``kind``) what a backend
    derived from one."""
    return root / ((f"{kind}-" if kind else "") + hashlib.sha256(key.encode()).hexdigest() + ".pkl")


def cached_entry(kind: str, key: str):
    """The entry kept under ``key`` in the terms' signed disk cache: a compiled term's functions
    (``kind`` ""), or a backend's entry of ``kind`` (say ``torch``) under a term's ``cache_key``
    and what else it depends on; None when there is none or the cache is off."""
    cache = _cache_root() if key else None
    if cache is None:
        return None
    path = _disk_cache_path(cache[0], key, kind)
    return _load(path, cache[1]) if path.is_file() else None


def store_entry(kind: str, key: str, entry) -> None:
    """Keep a backend's picklable ``entry`` of ``kind`` under ``key`` (see :func:`cached_entry`)."""
    cache = _cache_root() if key else None
    if cache is not None:
        _store(_disk_cache_path(cache[0], key, kind), cache[1], entry)


def _mac(key: bytes, path: Path, payload: bytes) -> bytes:
    # The entry's name is signed too: a valid entry copied under another name is refused.
    return hmac.new(key, path.name.encode() + b"\0" + payload, hashlib.sha256).digest()


def _load(path: Path, key: bytes):
    """The unpickled entry at ``path`` if its HMAC is valid, else None (reported once).
    Nothing is unpickled before the HMAC is checked."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    mac, payload = data[:32], data[32:]
    if len(data) < 32 or not hmac.compare_digest(mac, _mac(key, path, payload)):
        _warn_once("entry", f"stw: ignored a term cache entry not signed with your key ({path}: "
                            "written by an older stw, damaged, or planted); compiling afresh")
        return None
    try:
        return pickle.loads(payload)
    except Exception:  # written by another version of a library: compile again
        return None


def _store(path: Path, key: bytes, entry) -> None:
    try:
        payload = pickle.dumps(entry)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as out:
            out.write(_mac(key, path, payload) + payload)
        tmp.replace(path)   # atomic: concurrent runs never read half a file
    except (OSError, pickle.PicklingError, TypeError):
        pass  # caching is an optimization only


# The layout of a compiled term's disk entry, in its name: an entry of another layout (an older
# stw's, without ``affine``) is another name, so neither version reads the other's.
TERM_ENTRY = "|entry 2: pairs, affine, value, full"
# How abs, sign, min, max and atan2(u, ±u) are lowered (_convert): a key read off the sympy tree
# does not see it, so a change there must be a change of name (sign once made NaN a 0 in stored
# code, min and max dropped a NaN first argument, and atan2(u, u) read -pi/4 at u = 0).
LOWERING = "|lowering 3: sign, min and max pass NaN on; atan2(u, u) is 0 at u = 0"


def _build(expr: sp.Expr, variables: tuple[LocalVar, ...], parameters: tuple[str, ...]) -> CompiledTerm:
    text, e = tree_text(expr), None
    if text is not None:   # named without converting: a hit then converts nothing
        key = f"{text}|symengine {se.__version__}|{variables}|{parameters}"
    else:
        e = _to_symengine(expr)    # once: the key's text and, on a miss, what is compiled
        key = _term_key(e, variables, parameters)
    entry = cached_entry("", key + TERM_ENTRY + LOWERING)
    if entry is not None:
        pairs, affine, value_fn, full_fn = entry
        return CompiledTerm(expr=expr, variables=variables, parameters=parameters,
                            hessian_pairs=tuple(pairs), affine=affine, _value_fn=value_fn,
                            _full_fn=full_fn, cache_key=key)
    term = _compile(expr, variables, parameters, e)
    term.cache_key = key
    store_entry("", key + TERM_ENTRY + LOWERING, (term.hessian_pairs, term.affine, term._value_fn, term._full_fn))
    return term


def _compile(expr: sp.Expr, variables: tuple[LocalVar, ...], parameters: tuple[str, ...],
             e=None) -> CompiledTerm:
    """``expr`` compiled: its value, gradient and Hessian as symengine LLVM code (``e``: the
    expression already in symengine, when the caller has it)."""
    e = sign_as_piecewise(_to_symengine(expr) if e is None else e)
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
                        hessian_pairs=tuple(pairs), affine=_affine(e, var_syms, grad),
                        _value_fn=value_fn, _full_fn=full_fn)


def _affine(e, var_syms: list, grad: list) -> bool:
    """Whether ``e`` is affine in ``var_syms``: its gradient ``grad`` free of them, and ``e`` less
    the gradient's terms free of them too, once expanded (sign(x) has a zero gradient). Only
    what passes the first test is expanded: affine relations, a few terms each."""
    variables = set(var_syms)
    if any(g.free_symbols & variables for g in grad):
        return False
    rest = se.expand(e - se.Add(*[g * v for g, v in zip(grad, var_syms)]))
    return not (rest.free_symbols & variables)


def double_finite(expr: sp.Expr, values: dict[str, float] | None = None) -> bool:
    """Whether ``expr``, with symbols replaced by ``values``, and every part of it stay finite
    in double precision. Each node is evaluated once, by symengine in plain floating point
    (microseconds whatever the size), so exp(-exp(exp(100))) fails at its inner exp even though
    its value underflows to 0: sympy's exact evaluation of it, or even substituting 100.0 for a
    constant in it, would compute ever more digits, for ever.
    """
    try:
        root = _to_symengine(expr)
    except Exception:  # noqa: BLE001 - not convertible: leave it to the later checks
        return True
    subs = {se.Symbol(k): se.RealDouble(v) for k, v in (values or {}).items()}
    memo: dict = {}
    for node in _post_order(root):
        value = node
        try:
            value = node.func(*[memo[a] for a in node.args]) if node.args else subs.get(node, node)
            if not value.free_symbols:
                number = complex(value.n(53, real=False))
                if not (math.isfinite(number.real) and math.isfinite(number.imag)):
                    return False
                value = se.RealDouble(number.real) + se.I * se.RealDouble(number.imag) \
                    if number.imag else se.RealDouble(number.real)
        except Exception:  # noqa: BLE001 - a condition, a Piecewise: not a number to check
            pass
        memo[node] = value
    return True


def cache_size() -> int:
    """Number of compiled terms held (for tests and the status line)."""
    return len(_CACHE)
