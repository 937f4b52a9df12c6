"""Lowering of compiled terms to torch: our own sympy expressions become TorchScript programs.

The core hands every term over as a sympy expression (``CompiledTerm.expr``), built from parsed
trees, never from user text. Each term gets up to three programs, each built on first use: its
value alone, its value and gradient, and its value, gradient and the second derivatives of
``CompiledTerm.hessian_pairs``, differentiated by symengine once; their source is kept in the
terms' disk cache. A program is written from a graph of the operations (symengine's common
subexpressions shared, associated as the former printed programs were: the same numbers, bit
for bit) in whichever of two forms runs fewer torch ops, each of which costs about a microsecond
on the CPU (a kernel launch on a GPU) whatever it computes on a few hundred numbers:

- straight-line: one op per operation, on (n,) rows;
- levelled: the operations of one depth and kind as one op on rows of a register matrix R, their
  operands gathered or sliced (a basketball thrower's torque with its Hessian pairs, 36
  instances: 3022 operations, 2.4 ms straight-line, 0.8 ms levelled).

``torch.compile`` (Inductor) fused such programs into one loop but took 10-40 s to compile each
(basketball's: 197 s), more than any bundled session's whole solve.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import symengine as se
import sympy as sp
import torch

from stw_tui.sym.compiler import (CompiledTerm, LocalVar, _to_symengine, cached_entry, sign_as_piecewise,
                                  store_entry)
from stw_tui.sym.symbols import TIME, split_dof_symbol

_FUNCTIONS = {name: name for name in (
    "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh",
    "atanh", "log", "exp", "sqrt", "floor", "erf")} | {"Abs": "abs", "ceiling": "ceil"}
_RELATIONS = {"StrictLessThan": "lt", "LessThan": "le", "Equality": "eq", "Unequality": "ne",
              "StrictGreaterThan": "gt", "GreaterThan": "ge"}
_FLIPPED = {"lt": "gt", "le": "ge", "eq": "eq", "ne": "ne", "gt": "lt", "ge": "le"}
_BOOLEAN = {*_RELATIONS.values(), "logical_and", "logical_or", "logical_not"}
# What gives each number the same bits on a (rows, n) block as on an (n,) row: correctly rounded
# or exact. torch's other functions (sin, exp, general powers, ...) run vectorized in chunks and
# element by element at a row's end, which may differ in the last bit: one row each.
_EXACT = {"add", "sub", "mul", "div", "neg", "reciprocal", "sqrt", "abs", "floor", "ceil", "where", *_BOOLEAN}


class _Graph:
    """The operations of symengine expressions: node i is (op, attr, operands, depth), an
    operand a node's index or a float; nodes 0..inputs-1 are the program's inputs. Equal
    subexpressions and equal operations are one node."""

    def __init__(self, names: list[str]):
        self.nodes: list[tuple] = [("input", None, (), 0)] * len(names)
        self.index: dict = {se.Symbol(n): i for i, n in enumerate(names)}   # expression -> node
        self.operations: dict = {}                                           # (op, attr, operands) -> node
        self.inputs = len(names)

    def add(self, op: str, *operands, attr=None):
        if op == "div" and not isinstance(operands[0], int):   # a number over a tensor: as
            return self.add("mul", self.add("reciprocal", operands[1]), operands[0])   # TorchScript
        key = (op, attr, operands)
        found = self.operations.get(key)
        if found is None:
            depth = 1 + max((self.nodes[o][3] for o in operands if isinstance(o, int)), default=0)
            found = self.operations[key] = len(self.nodes)
            self.nodes.append((op, attr, operands, depth))
        return found

    def of(self, e):
        """The operand of expression ``e``: a node, or the float a number is.

        Raises:
            KeyError: a function the programs do not know.
        """
        if not e.free_symbols:
            return float(e)
        found = self.index.get(e)
        if found is None:
            found = self.index[e] = self._of(e)
        return found

    def _of(self, e):
        name, args = type(e).__name__, e.args
        if name == "Add":              # a - b rather than a + (-1)*b: one op, not two
            out = None
            for term in args:
                negative, x = self._signed(term)
                if out is None:
                    out = x if not negative else -x if isinstance(x, float) else self.add("neg", x)
                else:
                    out = self.add("sub" if negative else "add", out, x)
            return out
        if name == "Mul":
            return self._product(args)
        if name == "Pow":
            base, exponent = args
            if not base.free_symbols and float(base) == math.e:
                return self.add("exp", self.of(exponent))
            if exponent == se.Rational(1, 2):
                return self.add("sqrt", self.of(base))
            if not exponent.free_symbols:
                return self.add("pow", self.of(base), attr=int(exponent) if exponent.is_Integer else float(exponent))
            return self.add("pow", self.of(base), self.of(exponent))
        if name == "Piecewise":        # (value, condition) pairs, the last condition True
            pairs = list(zip(args[0::2], args[1::2]))
            out = self.of(pairs[-1][0])
            for value, condition in reversed(pairs[:-1]):
                out = self.add("where", self.of(condition), self.of(value), out)
            return out
        if name in ("And", "Or"):
            out = self.of(args[0])
            for a in args[1:]:
                out = self.add(f"logical_{name.lower()}", out, self.of(a))
            return out
        if name in _RELATIONS and not args[0].free_symbols:   # torch compares a tensor with a number
            return self.add(_FLIPPED[_RELATIONS[name]], self.of(args[1]), self.of(args[0]))
        op = _RELATIONS.get(name) or {"Not": "logical_not", "atan2": "atan2"}.get(name) or _FUNCTIONS[name]
        return self.add(op, *map(self.of, args))

    def _product(self, factors):
        """A product left to right, its factors of negative integer powers as divisors after it
        (a/b: one op, not two)."""
        above = [f for f in factors if not _divisor(f)]
        out = self.of(above[0]) if above else 1.0
        for f in above[1:]:
            out = self.add("mul", out, self.of(f))
        for f in factors:
            if _divisor(f):
                out = self.add("div", out, self.of(f.args[0] ** -int(f.args[1])))
        return out

    def _signed(self, term) -> tuple[bool, object]:
        """(whether negative, the operand of the term without its sign) of one term of a sum."""
        if not term.free_symbols:
            value = float(term)
            return value < 0, abs(value)
        if type(term).__name__ == "Mul" and not term.args[0].free_symbols and float(term.args[0]) < 0:
            coefficient, rest = -float(term.args[0]), term.args[1:]
            return True, self._product(rest if coefficient == 1.0 else (se.RealDouble(coefficient), *rest))
        return False, self.of(term)


def _divisor(f) -> bool:
    return type(f).__name__ == "Pow" and f.args[1].is_Integer and int(f.args[1]) < 0


def _numbers_inlined(replacements, reduced):
    """cse's output without its subexpressions that are numbers (tanh(1/3) shared by two
    terms): each goes back where it was used, and becomes the float it computes there."""
    numbers, kept = {}, []
    for name, sub in replacements:
        sub = sub.xreplace(numbers) if numbers else sub
        if sub.free_symbols:
            kept.append((name, sub))
        else:
            numbers[name] = sub
    return kept, [e.xreplace(numbers) for e in reduced] if numbers else reduced


_OPERATORS = {"add": "+", "sub": "-", "mul": "*", "div": "/"}


def _render(op: str, attr, args: list[str]) -> str:
    if op in _OPERATORS:
        return f"({args[0]} {_OPERATORS[op]} {args[1]})"
    return f"torch.{op}({', '.join([*args, *([repr(attr)] if attr is not None else [])])})"


class _Source:
    """A program's source lines and the arrays it reads (its argument A)."""

    def __init__(self):
        self.lines: list[str] = []
        self.arrays: list[np.ndarray] = []

    def array(self, values, dtype=np.float64) -> str:
        self.arrays.append(np.asarray(values, dtype=dtype))
        return f"A[{len(self.arrays) - 1}]"

    def number(self, values: list[float], op: str, first: bool = False, column: bool = False) -> str:
        """Numbers as an operand: a float, or a (1, 1) or (rows, 1) tensor where they differ
        or torch takes tensors only (where, atan2; ``first``: the first operand of an op with
        ``out=``, which has no form with a number there, but for pow)."""
        if len(set(values)) == 1 and op not in ("where", "atan2") and (not first or op == "pow"):
            return repr(float(values[0]))
        return self.array(np.reshape(values if len(set(values)) > 1 else values[:1], (-1, 1) if column else (-1,)))


def _straight(graph: _Graph, roots: list, k: int, params: int) -> tuple[_Source, int]:
    """The straight-line program of ``roots`` and the torch ops it runs."""
    src = _Source()
    name = [f"x{i}" for i in range(len(graph.nodes))]
    name[k] = "t"
    for i in range(graph.inputs, len(graph.nodes)):
        op, attr, operands, _ = graph.nodes[i]
        # a number beside atan2's tensor is filled like it, as the programs before these did
        args = [name[o] if isinstance(o, int) else src.number([o], op) if op != "atan2" else
                f"torch.full_like({name[next(a for a in operands if isinstance(a, int))]}, {o!r})"
                for o in operands]
        src.lines.append(f"    x{i} = {_render(op, attr, args)}")
    out = [name[o] if isinstance(o, int) else f"torch.full_like(t, {o!r})" for o in roots]
    src.lines.insert(0, f"    {''.join(f'x{i}, ' for i in range(k))}= X.unbind(0)")
    if params:     # rows of the parameters: every operation's result is an (n,) row
        src.lines.insert(1, f"    {''.join(f'x{k + 1 + j}, ' for j in range(params))}= "
                            f"p.unsqueeze(1).expand({params}, t.shape[0]).unbind(0)")
    src.lines.append(f"    return torch.stack([{', '.join(out)}])")
    return src, len(graph.nodes) - graph.inputs + 2 + sum(not isinstance(o, int) for o in roots)


def _levelled(graph: _Graph, roots: list, k: int, params: int) -> tuple[_Source, int]:
    """The levelled program of ``roots`` and the torch ops it runs (results written by ``out=``:
    not one autograd goes back through)."""
    src = _Source()
    nodes = graph.nodes
    boolean = [n[0] in _BOOLEAN for n in nodes]
    row = {i: i for i in range(graph.inputs)}
    used = {False: graph.inputs, True: 0}          # rows of R (floats) and Q (booleans) given out
    numbers = [o for o in roots if not isinstance(o, int)]
    if numbers:
        src.lines.append(f"    R[{used[False]}:{used[False] + len(numbers)}] = {src.array(np.reshape(numbers, (-1, 1)))}")
        number_rows = iter(range(used[False], used[False] + len(numbers)))
        used[False] += len(numbers)
    ops = 6
    levels: dict[tuple, list[int]] = {}
    for i in range(graph.inputs, len(nodes)):
        op, attr, operands, depth = nodes[i]
        kinds = tuple(boolean[o] if isinstance(o, int) else None for o in operands)
        exact = op in _EXACT or (op == "pow" and attr in (2, 3))   # else one op per row (see _EXACT)
        levels.setdefault((depth, op, repr(attr), kinds, None if exact else i), []).append(i)
    for (_, op, _, kinds, _), members in sorted(levels.items(), key=lambda item: item[0][0]):
        members.sort(key=lambda i: [row[o] if isinstance(o, int) else -1 for o in nodes[i][2]])
        args = []
        for j, kind in enumerate(kinds):
            column = [nodes[i][2][j] for i in members]
            if kind is None:
                args.append(src.number(column, op, first=j == 0, column=True))
                ops += 1
                continue
            matrix, rows = "Q" if kind else "R", [row[o] for o in column]
            if len(set(rows)) == 1 or rows == list(range(rows[0], rows[0] + len(rows))):   # a slice
                args.append(f"{matrix}[{rows[0]}:{rows[0] + len(set(rows))}]")
            else:
                args.append(f"torch.index_select({matrix}, 0, {src.array(rows, np.int64)})")
                ops += 1
            ops += 1
        flag = boolean[members[0]]
        start = used[flag]
        row.update((i, start + m) for m, i in enumerate(members))
        used[flag] += len(members)
        target = f"{'Q' if flag else 'R'}[{start}:{start + len(members)}]"
        attr = nodes[members[0]][1]
        src.lines.append(f"    torch.{op}({', '.join([*args, *([repr(attr)] if attr is not None else [])])}, out={target})")
        ops += 3
    out = [row[o] if isinstance(o, int) else next(number_rows) for o in roots]
    src.lines.append(f"    return torch.index_select(R, 0, {src.array(out, np.int64)})")
    head = [f"    R = torch.empty([{used[False]}, t.shape[0]], dtype=X.dtype, device=X.device)",
            f"    R[0:{k}] = X", f"    R[{k}] = t"]
    if used[True]:
        head.append(f"    Q = torch.empty([{used[True]}, t.shape[0]], dtype=torch.bool, device=X.device)")
    if params:
        head.append(f"    R[{k + 1}:{k + 1 + params}] = p.unsqueeze(1)")
    src.lines[:0] = head
    return src, ops


def _script(source: str):
    """The TorchScript function ``program`` of ``source``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # TorchScript's deprecation notices
        return torch.jit.CompilationUnit(source).program


def _compile(names: list[str], k: int, outputs: list, levelled: bool = True) -> tuple[str, list]:
    """The source of ``program(X, t, p, A)`` computing symengine ``outputs`` in ``names``
    (k variables, time, parameters) and its arrays A: X (k, n), t (n,), p (P,) give the
    (len(outputs), n) rows. The cheaper of its two forms (straight-line only: not ``levelled``)."""
    graph = _Graph(names)
    replacements, reduced = _numbers_inlined(*se.cse(outputs))
    for symbol, sub in replacements:     # common subexpressions as symengine shares them: the
        graph.index[symbol] = graph.of(sub)   # same association, so the same numbers, as before
    roots = [graph.of(e) for e in reduced]
    params = len(names) - k - 1
    forms = [_straight(graph, roots, k, params), *([_levelled(graph, roots, k, params)] if levelled else [])]
    src, _ = min(forms, key=lambda pair: pair[1])
    head = "def program(X: torch.Tensor, t: torch.Tensor, p: torch.Tensor, A: List[torch.Tensor]):\n"
    return head + "".join(line + "\n" for line in src.lines), src.arrays


@dataclass(eq=False)
class Program:
    """A compiled program of (k, n) variable values, (n,) times and (P,) parameters, giving
    ``rows`` rows (n,); its arrays copied to each device it runs on."""

    fn: object
    arrays: list
    on: dict = field(default_factory=dict)   # device -> the arrays there

    def arrays_on(self, device: torch.device) -> list[torch.Tensor]:
        """Its arrays as tensors on ``device`` (made once)."""
        if device not in self.on:
            self.on[device] = [torch.as_tensor(a, device=device) for a in self.arrays]
        return self.on[device]

    def __call__(self, X: torch.Tensor, times: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The (rows, n) outputs. Run inside :func:`unoptimized` (once for many calls)."""
        return self.fn(X, times, params, self.arrays_on(X.device))


# The version of the programs in the disk cache: raise it when what a program computes, or how
# it is written, changes (a cached program is then written afresh).
PRINTING = 5


@dataclass(eq=False)
class LoweredTerm:
    """A term as torch programs of (k, n) variable values, (n,) times and (P,) parameters, kept
    in the terms' disk cache under its ``cache_key``: a new process compiles them from there,
    without derivatives (basketball: 0.5 s of its first torch iterate) and without ``expr``."""

    term: CompiledTerm
    names: tuple             # the renamed symbols: variables, time, parameters
    programs: dict = field(default_factory=dict)   # kind ("value", "first", "full") -> Program
    _expr: object = None

    @property
    def expr(self):
        """The term in symengine, in the renamed symbols (made on first use)."""
        if self._expr is None:
            self._expr = _renamed(self.term, self.names)
        return self._expr

    @property
    def k(self) -> int:
        """How many variables (values and derivatives) the term takes per instance."""
        return self.term.k

    def program(self, kind: str) -> Program:
        """The program ``kind`` ("value", "first" or "full"), from the disk cache where it is kept."""
        found = self.programs.get(kind)
        if found is None:
            name = f"full{self.term.hessian_pairs}" if kind == "full" else kind
            key = f"{PRINTING}|{torch.__version__}|{name}|{self.term.cache_key}" if self.term.cache_key else ""
            entry = cached_entry("torch", key)
            if entry is None:
                # straight-line values: derivatives=autograd differentiates them
                entry = _compile(list(self.names), self.k, self._outputs(kind), levelled=kind != "value")
                store_entry("torch", key, entry)
            found = self.programs[kind] = Program(_script(entry[0]), entry[1])
        return found

    def _outputs(self, kind: str) -> list:
        """The symengine expressions that program ``kind`` computes."""
        if kind == "value":
            return [self.expr]
        variables = [se.Symbol(name) for name in self.names[:self.k]]
        grad = [self.expr.diff(v) for v in variables]
        if kind == "first":
            return [self.expr, *grad]
        return [self.expr, *grad, *(grad[a].diff(variables[b]) for a, b in self.term.hessian_pairs)]

    def rows(self, kind: str, X: torch.Tensor, times: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """(rows, n): program ``kind``'s rows at n instances: the values, then (but for
        "value") the k first derivatives, then (for "full") the second derivatives of
        ``term.hessian_pairs`` in their order."""
        with unoptimized():
            return self.program(kind)(X, times, params)

    def __call__(self, X: torch.Tensor, times: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """(n,): the term's values at n instances."""
        return self.rows("value", X, times, params)[0]


def unoptimized():
    """Programs run without TorchScript's optimizing: its profiling runs cost more than they save."""
    return torch.jit.optimized_execution(False)


_CACHE: dict[int, LoweredTerm] = {}


def _names(term: CompiledTerm) -> tuple[str, ...]:
    """The programs' argument names: variables ``_v0``…, time ``_t``, parameters ``_p0``…"""
    return (*(f"_v{i}" for i in range(term.k)), "_t", *(f"_p{i}" for i in range(len(term.parameters))))


def _fold_numbers(expr: sp.Expr) -> sp.Expr:
    """Replace function calls of numbers (``sin(2)``, ``sqrt(2)``) by floats."""
    return expr.replace(lambda e: isinstance(e, (sp.Function, sp.Pow)) and not e.free_symbols and e.is_number
                        and not e.is_Atom, lambda e: sp.Float(e.evalf(20), 20))


def _renamed(term: CompiledTerm, names: tuple[str, ...]):
    """``term.expr`` in symengine, its symbols renamed to ``names`` (:func:`_names`) and numeric
    calls folded to floats."""
    k = term.k
    variables = dict(zip(term.variables, names[:k]))
    params = dict(zip(term.parameters, names[k + 1:]))
    rename = {}
    for symbol in term.expr.free_symbols:
        if symbol == TIME:
            rename[symbol] = sp.Symbol(names[k])
            continue
        name, order = split_dof_symbol(symbol)
        var = LocalVar(name, order)
        if var in variables:
            rename[symbol] = sp.Symbol(variables[var])
        elif name in params and order == 0:
            rename[symbol] = sp.Symbol(params[name])
        else:  # compile_term guarantees this never happens
            raise ValueError(f"symbol {symbol} of term {term.expr} is neither variable nor constant")
    return sign_as_piecewise(_to_symengine(_fold_numbers(term.expr.xreplace(rename))))


def lower(term: CompiledTerm) -> LoweredTerm:
    """The torch programs of ``term`` (cached per compiled term, which the core itself caches)."""
    cached = _CACHE.get(id(term))
    if cached is not None and cached.term is term:
        return cached
    lowered = LoweredTerm(term, _names(term))
    _CACHE[id(term)] = lowered
    return lowered
