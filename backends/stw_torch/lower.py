"""Lowering of compiled terms to torch: our own sympy expressions become torch programs.

The core hands every term over as a sympy expression (``CompiledTerm.expr``) in DOF symbols
(``x``, ``x'``, ``x''``), time ``t`` and constant symbols. It was built from parsed trees, never
from user text, so it may be printed to Python source and compiled, as ``sympy.lambdify`` does.
Symbols are renamed to plain identifiers first (``x''`` is not one) and numeric function calls
such as ``sin(2)`` are folded to floats (torch functions take tensors only).

Each term gets up to three straight-line programs, each built on first use (for tensors, and on
the CPU for numpy arrays): its value alone (line searches, `when` conditions), its value and
gradient (:meth:`LoweredTerm.first_rows`, for Gauss-Newton steps), and its value, gradient and
the second derivatives of ``CompiledTerm.hessian_pairs`` (:meth:`LoweredTerm.rows`), their
common subexpressions shared within each program. The derivatives are taken symbolically, by
symengine after the core's own conversion (min, max and abs become Piecewise), once per term;
the printed source is kept in the terms' disk cache (LoweredTerm), so a new process compiles it
without the symbolic work. Measured on 2 cores (acrobat, 41 ms per iteration): a torch op on a few hundred
numbers costs microseconds whatever it computes, and autograd's backward and batched
double-backward passes ran several times the ops of the program plus the tape (31 ms of
evaluation against 4 ms for the program of the largest term).

A program is compiled by TorchScript where it can be (~2.5x fewer microseconds per op than
Python calling torch; the same aten kernels, so the same numbers), run without the graph
executor's optimizations (its profiling runs cost more than they save here), and as plain
Python otherwise. On the CPU the same TorchScript source runs over numpy arrays instead, its
syntax tree interpreted as a tape of numpy operations (:func:`host.host_function`: about 0.6 of
TorchScript's microseconds per op, no TorchScript compile, and no Python evaluation of any text): its arithmetic is
numpy's, correctly rounded like torch's, and its functions torch's own, so the numbers are the
same bit for bit.

``torch.compile`` (Inductor, CPU, torch 2.13) was measured on the same printed programs (value,
gradient and Hessian pairs; one thread): it fuses a program into one loop, and gave the same
numbers as the program on every input tried. Per call, basketball's 30 programs (192 instances
each) took 1.7 ms against the host tapes' 5.8 ms run one by one, the arm's 9 took 0.35 against
0.61; one of basketball's effort terms took 0.08, 0.15 and 0.54 ms at 192, 1920 and 9600
instances against 0.27, 1.2 and 6.9 (the core's symengine functions of the same term, which the
scipy backend runs: 0.03, 0.20 and 1.06). But compiling costs 10-40 s per program (197 s for
basketball's, one shape each; a shape-generic compile of that effort term 18 s), and with
Inductor's disk cache warm still 4.4 s for the arm's: more than any bundled session's whole
solve, and the first `iterate` is to take under a second. Not adopted: it would pay only on
windows of thousands of instances solved for many iterations.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import symengine as se
import sympy as sp
import torch
from sympy.printing.pytorch import TorchPrinter

from stw_tui.sym.compiler import (CompiledTerm, LocalVar, _to_symengine, cached_entry, sign_as_piecewise,
                                  store_entry)
from stw_tui.sym.symbols import TIME, split_dof_symbol

from .host import host_function, tape_of


class _Printer(TorchPrinter):
    """sympy's torch printer, with every float printed exactly (repr round-trips a double)."""

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_atan2(self, expr):
        return _atan2_filled(expr.args, self._print, lambda a: repr(float(a)))


def _fold_numbers(expr: sp.Expr) -> sp.Expr:
    """Replace function calls of numbers (``sin(2)``, ``sqrt(2)``) by floats."""
    def numeric_call(e) -> bool:
        return (isinstance(e, (sp.Function, sp.Pow)) and not e.free_symbols and e.is_number
                and not e.is_Atom)

    return expr.replace(numeric_call, lambda e: sp.Float(e.evalf(20), 20))


@dataclass(eq=False)
class Program:
    """A compiled straight-line torch program of n-long inputs with ``rows`` outputs; outputs
    that are numbers are not computed but filled in (``constants``: row -> value).

    A program from TorchScript source may run on the host instead (:meth:`host`, CPU only):
    the same source's tape run over numpy arrays (:func:`host.host_function`)."""

    fn: object               # the torch function (None: a program for the host only)
    rows: int
    constants: dict
    host_fn: object = None   # the same program over numpy arrays (None: through ``fn``)
    # The constant rows as tensors, by (row, n, dtype, device): filling them anew was a sixth of
    # cat_mouse's program calls. Shared between calls: every consumer concatenates or stacks
    # the rows it gets, none writes into them.
    filled: dict = field(default_factory=dict, repr=False)

    def __call__(self, inputs: list[torch.Tensor], like: torch.Tensor) -> list[torch.Tensor]:
        """The rows, each (n,) like ``like``. Run inside :func:`unoptimized` (once for many calls)."""
        n = like.shape[0]
        computed = iter(self.fn(*inputs))
        out = []
        for row in range(self.rows):
            value = self.constants.get(row)
            if value is not None:
                out.append(self._filled(row, value, n, like))
                continue
            value = next(computed)
            if not isinstance(value, torch.Tensor):
                value = torch.full((n,), float(value), dtype=like.dtype, device=like.device)
            elif value.dtype != like.dtype:
                value = value.to(like.dtype)
            out.append(value.expand(n) if value.shape != (n,) else value)
        return out

    def host(self, inputs: list[np.ndarray], times: np.ndarray) -> list[np.ndarray]:
        """:meth:`__call__` on numpy arrays (``times``: the (n,) times, for the rows' length),
        the same numbers as numpy arrays; through the torch function where there is no host one."""
        if self.host_fn is None:
            with unoptimized():
                return [r.numpy() for r in self([torch.from_numpy(a) for a in inputs], torch.from_numpy(times))]
        with np.errstate(all="ignore"):   # inf and nan come out silently, as from TorchScript
            out = self.host_fn(*inputs)
        return self.finish(out, times.shape[0])

    def finish(self, out: list, n: int, loose: tuple | None = None) -> list[np.ndarray]:
        """The rows of :meth:`host` from the host function's outputs ``out`` on n instances: the
        constant rows filled in, and every row an (n,) float64 array. ``loose``: the positions
        in ``out`` that may be anything else (the rest are known to be rows, host_levels'
        LevelPlan.loose); None: any of them."""
        for i in range(len(out)) if loose is None else loose:
            out[i] = as_row(out[i], n)
        if self.constants:
            computed = iter(out)
            out = [self._filled(row, self.constants[row], n, None) if row in self.constants else next(computed)
                   for row in range(self.rows)]
        return out

    def _filled(self, row: int, value, n: int, like: torch.Tensor | None):
        """Row ``row``, the number ``value`` n times: a tensor like ``like``, or (None) an array."""
        key = (row, n, like.dtype, like.device) if like is not None else (row, n)
        tensor = self.filled.get(key)
        if tensor is None:
            if len(self.filled) >= FILLED_KEPT:   # sizes come and go (windows, batches)
                self.filled.clear()
            tensor = self.filled[key] = (
                torch.full((n,), float(value), dtype=like.dtype, device=like.device) if like is not None
                else np.full(n, float(value)))
        return tensor


FILLED_KEPT = 64   # constant rows a program keeps filled


def as_row(value, n: int) -> np.ndarray:
    """A host program's output as an (n,) float64 array: a number or a 0-d array repeated, a
    test's bools as 0/1 (as torch's ``.to()`` makes them); an (n,) float64 array as it is."""
    if value.__class__ is not np.ndarray or value.shape != (n,) or value.dtype != np.float64:
        value = np.asarray(value, dtype=np.float64)
        return np.broadcast_to(value, (n,)) if value.shape != (n,) else value
    return value


_FUNCTIONS = {name: f"torch.{name}" for name in (
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "asinh", "acosh",
    "atanh", "log", "exp", "sqrt", "sign", "floor", "erf")} | {"Abs": "torch.abs", "ceiling": "torch.ceil"}
_RELATIONS = {"StrictLessThan": ("<", ">"), "LessThan": ("<=", ">="), "Equality": ("==", "=="),
              "Unequality": ("!=", "!="), "StrictGreaterThan": (">", "<"), "GreaterThan": (">=", "<=")}


def _number(value: float) -> str:
    text = repr(float(value))
    return f"({text})" if text.startswith("-") else text


def _print(e) -> str:
    """torch source of a symengine expression (printed directly: sympy's printer took 0.8 s of
    acrobat's 0.9 s lowering). Raises KeyError on a construct it does not know."""
    if e.is_Symbol:
        return e.name
    if not e.free_symbols:
        return _number(float(e))          # numbers, constants and functions of them
    name = type(e).__name__
    args = e.args
    if name == "Add":                    # a - b rather than a + (-1)*b: one op, not two
        terms = [_signed(a) for a in args]
        out = terms[0][1] if terms[0][0] == "+" else f"-{terms[0][1]}"
        return "(" + out + "".join(f" {sign} {text}" for sign, text in terms[1:]) + ")"
    if name == "Mul":
        return _product(args)
    if name == "Pow":
        base, exponent = args
        if not base.free_symbols and float(base) == math.e:
            return f"torch.exp({_print(exponent)})"
        if exponent == se.Rational(1, 2):
            return f"torch.sqrt({_print(base)})"
        power = str(int(exponent)) if exponent.is_Integer else _print(exponent)
        return f"torch.pow({_print(base)}, {power})"
    if name == "Piecewise":              # (value, condition) pairs, the last condition True
        pairs = list(zip(args[0::2], args[1::2]))
        out, number = _print(pairs[-1][0]), not pairs[-1][0].free_symbols
        for value, condition in reversed(pairs[:-1]):
            test, chosen = _print(condition), _print(value)
            if number and not value.free_symbols:    # where() of two floats is float32
                chosen = f"torch.full_like({test}, {chosen}, dtype=torch.float64)"
            out, number = f"torch.where({test}, {chosen}, {out})", False
        return out
    if name in _RELATIONS:               # a number on the left would need a reflected operator
        left, right = args
        op, flipped = _RELATIONS[name]
        if not left.free_symbols:
            return f"({_print(right)} {flipped} {_print(left)})"
        return f"({_print(left)} {op} {_print(right)})"
    if name in ("And", "Or"):
        out = _print(args[0])
        for a in args[1:]:
            out = f"torch.logical_{name.lower()}({out}, {_print(a)})"
        return out
    if name == "Not":
        return f"torch.logical_not({_print(args[0])})"
    if name == "atan2":
        return _atan2_filled(args, _print, lambda a: _number(float(a)))
    return f"{_FUNCTIONS[name]}({', '.join(_print(a) for a in args)})"


def _atan2_filled(args, show, number) -> str:
    """``torch.atan2`` of ``args`` printed by ``show``. torch.atan2 takes tensors only, so a
    number (printed by ``number``) is filled like the other argument: the same elementwise
    atan2 as of the number itself. Both printers (ours, and sympy's for the fallback) use it."""
    like = next((show(a) for a in args if a.free_symbols), None)
    return "torch.atan2(" + ", ".join(
        show(a) if a.free_symbols else f"torch.full_like({like}, {number(a)}, dtype=torch.float64)"
        for a in args) + ")"


def _signed(term) -> tuple[str, str]:
    """("+" or "-", the term's torch source without its sign) of one term of a sum."""
    if not term.free_symbols:
        value = float(term)
        return ("-" if value < 0 else "+"), repr(abs(value))
    if type(term).__name__ == "Mul" and not term.args[0].free_symbols and float(term.args[0]) < 0:
        rest = term.args[1:]
        coefficient = -float(term.args[0])
        return "-", _product(rest if coefficient == 1.0 else (se.RealDouble(coefficient), *rest))
    return "+", _print(term)


def _product(factors) -> str:
    """A product, its factors of negative integer powers as divisors (a/b: one op, not two)."""
    above, below = [], []
    for f in factors:
        if type(f).__name__ == "Pow" and f.args[1].is_Integer and int(f.args[1]) < 0:
            exponent = -int(f.args[1])
            below.append(_print(f.args[0]) if exponent == 1 else f"torch.pow({_print(f.args[0])}, {exponent})")
        else:
            above.append(_print(f))
    out = "*".join(above) if above else "1.0"
    return "(" + out + "".join(f"/{b}" for b in below) + ")"


def _constant(e) -> float | None:
    try:
        return float(e) if not e.free_symbols else None
    except (RuntimeError, TypeError, ValueError):
        return None


def _script(source: str):
    """The TorchScript function ``program`` of ``source``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # TorchScript's deprecation notices
        return torch.jit.CompilationUnit(source).program


# What the printed programs may call as ``torch.…`` when run on the host (host.host_function)
_HOST_NAMES = (*(f.removeprefix("torch.") for f in _FUNCTIONS.values()),
               "where", "full_like", "logical_and", "logical_or", "logical_not")


def _compile(names: list[str], outputs: list) -> tuple[Program, str | None]:
    """The program of symengine ``outputs`` in the variables ``names``, common subexpressions
    shared, and its TorchScript source (None: compiled as plain Python instead)."""
    replacements, reduced = _numbers_inlined(*se.cse(outputs))
    constants = {row: value for row, e in enumerate(reduced) if (value := _constant(e)) is not None}
    computed = [e for row, e in enumerate(reduced) if row not in constants]
    try:
        source = (f"def program({', '.join(names)}):\n"
                  + "".join(f"    {name} = {_print(sub)}\n" for name, sub in replacements)
                  + f"    return [{', '.join(_print(e) for e in computed)}]\n")
        fn = _script(source)
    except Exception:  # noqa: BLE001 - a construct either does not take: sympy's printer, plain Python
        shared = [(name._sympy_(), _fold_numbers(sub._sympy_())) for name, sub in replacements]
        exprs = [_fold_numbers(e._sympy_()) for e in computed]
        fn = sp.lambdify([sp.Symbol(name) for name in names], exprs, modules="torch",
                         printer=_Printer, cse=lambda _exprs: (shared, exprs))
        source = None
    return Program(fn, len(reduced), constants), source


def _numbers_inlined(replacements, reduced):
    """cse's output without its subexpressions that are numbers (tanh(1/3) shared by two
    terms): each goes back where it was used, where the printer folds it into the float it
    computes. As a name of its own it would reach a torch function as a float (torch.asin(x1)),
    which TorchScript turns into a tensor and torch itself refuses."""
    numbers, kept = {}, []
    for name, sub in replacements:
        sub = sub.xreplace(numbers) if numbers else sub
        if sub.free_symbols:
            kept.append((name, sub))
        else:
            numbers[name] = sub
    return kept, [e.xreplace(numbers) for e in reduced] if numbers else reduced


# The version of the printed programs in the disk cache: raise it when printing changes what a
# term's program computes (a cached program is then printed afresh).
PRINTING = 3
TAPES = 1      # the version of host.tape_of's tapes in the disk cache


@dataclass(eq=False)
class LoweredTerm:
    """A term as torch programs of (k, n) variable values, (n,) times and parameter scalars.

    Each program's TorchScript source is kept in the terms' disk cache under the term's
    ``cache_key`` (stw_tui.sym.compiler.cached_entry): a new process compiles it from there,
    without taking derivatives, sharing subexpressions and printing again (basketball: 0.5 s of
    its first torch iterate), and without ``expr`` at all.
    """

    term: CompiledTerm
    names: tuple             # the renamed symbols: variables, time, parameters
    # (kind, host) -> Program, each built on first use: kind "value" (the value alone), "first"
    # (value and gradient) or "full" (value, gradient and Hessian pairs); host: run on numpy
    programs: dict = field(default_factory=dict)
    _expr: object = None

    @property
    def expr(self):
        """The term in symengine, in the renamed symbols (made on first use)."""
        if self._expr is None:
            self._expr = _renamed(self.term, self.names)
        return self._expr

    def program(self, kind: str, host: bool = False) -> Program:
        """The program ``kind`` ("value", "first" or "full"), for tensors or (``host``) numpy."""
        found = self.programs.get((kind, host))
        if found is None:
            found = self.programs[(kind, host)] = self._program(kind, host)
        return found

    def _outputs(self, kind: str) -> list:
        """The symengine expressions that program ``kind`` computes."""
        if kind == "value":
            return [self.expr]
        variables = [se.Symbol(name) for name in self.names[:self.term.k]]
        grad = [self.expr.diff(v) for v in variables]
        if kind == "first":
            return [self.expr, *grad]
        return [self.expr, *grad, *(grad[a].diff(variables[b]) for a, b in self.term.hessian_pairs)]

    def _program(self, kind: str, host: bool) -> Program:
        """Program ``kind`` from the disk cache where its source is kept, else compiled (and
        kept). A host program is the source's tape (:func:`host.tape_of`) run on numpy arrays,
        with no TorchScript compile at all."""
        name = f"full{self.term.hessian_pairs}" if kind == "full" else kind
        key = f"{PRINTING}|{torch.__version__}|{name}|{self.term.cache_key}" if self.term.cache_key else ""
        entry = cached_entry("torch", key)
        if entry is not None:
            source, rows, constants = entry
            tape = self._tape(key, source) if host else None
            if tape is not None:
                return Program(None, rows, constants, host_function(tape, _HOST_NAMES))
            try:
                return Program(_script(source), rows, constants)
            except Exception:  # noqa: BLE001 - a source this torch no longer takes: print it afresh
                pass
        program, source = _compile(list(self.names), self._outputs(kind))
        if source is not None:
            store_entry("torch", key, (source, program.rows, program.constants))
            tape = self._tape(key, source) if host else None
            if tape is not None:
                program.host_fn = host_function(tape, _HOST_NAMES)
        return program

    @staticmethod
    def _tape(key: str, source: str) -> tuple | None:
        """The host tape of ``source`` (host.tape_of), kept in the disk cache beside it: a new
        process reads it without parsing (basketball: 0.24 s of parsing 129 sources)."""
        key = f"{TAPES}|{key}" if key else ""
        tape = cached_entry("torch-tape", key)
        if tape is None:
            tape = tape_of(source, _HOST_NAMES)
            if tape is not None:
                store_entry("torch-tape", key, tape)
        return tape

    @property
    def k(self) -> int:
        """How many variables (values and derivatives) the term takes per instance."""
        return self.term.k

    def __call__(self, X: torch.Tensor, times: torch.Tensor, params: list[torch.Tensor]) -> torch.Tensor:
        """(n,): the term's values at n instances."""
        with unoptimized():
            return self.values(X, times, params)

    def values(self, X: torch.Tensor, times: torch.Tensor, params: list[torch.Tensor]) -> torch.Tensor:
        """(n,): the term's values at n instances. Run inside :func:`unoptimized`."""
        return self.program("value")([*X.unbind(0), times, *params], times)[0]

    def first_rows(self, X: torch.Tensor, times: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
        """1 + k rows (n,): the values and the k first derivatives at each of the n instances.
        Run inside :func:`unoptimized`."""
        return self.program("first")([*X.unbind(0), times, *params], times)

    def rows(self, X: torch.Tensor, times: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
        """1 + k + pairs rows (n,): the values, the k first derivatives and the second
        derivatives of ``term.hessian_pairs`` (in their order) at each of the n instances.
        Run inside :func:`unoptimized`."""
        return self.program("full")([*X.unbind(0), times, *params], times)

    def host_rows(self, kind: str, X: np.ndarray, times: np.ndarray, params: list[np.ndarray]) -> list[np.ndarray]:
        """The rows of program ``kind`` (:meth:`values`, :meth:`first_rows`, :meth:`rows`) on
        numpy arrays, the same numbers as numpy (CPU only): X (k, n), params 0-d arrays."""
        return self.program(kind, host=True).host([*X, times, *params], times)

    def full(self, X: torch.Tensor, times: torch.Tensor, params: list[torch.Tensor]) -> torch.Tensor:
        """(1 + k + pairs, n): :meth:`rows` stacked."""
        with unoptimized():
            return torch.stack(self.rows(X, times, params))


def unoptimized():
    """Programs run without the TorchScript graph executor's optimization passes: its profiling
    runs and guards cost more than they save on straight-line programs of small tensors."""
    return torch.jit.optimized_execution(False)


_CACHE: dict[int, LoweredTerm] = {}


def _names(term: CompiledTerm) -> tuple[str, ...]:
    """The programs' argument names: variables ``_v0``…, time ``_t``, parameters ``_p0``…"""
    return (*(f"_v{i}" for i in range(term.k)), "_t", *(f"_p{i}" for i in range(len(term.parameters))))


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
    return sign_as_piecewise(_to_symengine(_fold_numbers(term.expr.xreplace(rename))))   # a sympy object


def lower(term: CompiledTerm) -> LoweredTerm:
    """The torch programs of ``term`` (cached per compiled term, which the core itself caches)."""
    cached = _CACHE.get(id(term))
    if cached is not None and cached.term is term:
        return cached
    lowered = LoweredTerm(term, _names(term))
    _CACHE[id(term)] = lowered
    return lowered
