"""Lowering of compiled terms to torch: our own sympy expressions become torch callables.

The core hands every term over as a sympy expression (``CompiledTerm.expr``) in DOF symbols
(``x``, ``x'``, ``x''``), time ``t`` and constant symbols. It was built from parsed trees, never
from user text, so ``sympy.lambdify`` may print it to Python source. Symbols are renamed to plain
identifiers first (``x''`` is not one), numeric function calls such as ``sin(2)`` are folded to
floats (torch functions take tensors only) and ``min``/``max`` accept Python numbers.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import sympy as sp
import torch

from stw_tui.sym.compiler import CompiledTerm, LocalVar
from stw_tui.sym.symbols import TIME, split_dof_symbol


def _as_tensor(value, like: torch.Tensor) -> torch.Tensor:
    if isinstance(value, torch.Tensor):
        return value
    return torch.as_tensor(float(value), dtype=like.dtype, device=like.device)


def _reduce(op, args):
    like = next((a for a in args if isinstance(a, torch.Tensor)), None)
    if like is None:  # all numbers (sympy folds these, but be safe)
        return float((max if op is torch.maximum else min)(args))
    return functools.reduce(op, [_as_tensor(a, like) for a in args])


def _maximum(*args):
    return _reduce(torch.maximum, args)


def _minimum(*args):
    return _reduce(torch.minimum, args)


# Looked up before sympy's torch namespace: the torch printer prints Max/Min as max/min.
_OVERRIDES = {"max": _maximum, "min": _minimum, "Max": _maximum, "Min": _minimum}


def _fold_numbers(expr: sp.Expr) -> sp.Expr:
    """Replace function calls of numbers (``sin(2)``, ``sqrt(2)``) by floats."""
    def numeric_call(e) -> bool:
        return (isinstance(e, (sp.Function, sp.Pow)) and not e.free_symbols and e.is_number
                and not e.is_Atom)

    return expr.replace(numeric_call, lambda e: sp.Float(e.evalf(20), 20))


@dataclass(eq=False)
class LoweredTerm:
    """A term as a torch function of (k, n) variable values, (n,) times and parameter scalars."""

    term: CompiledTerm
    fn: object

    @property
    def k(self) -> int:
        """How many variables (values and derivatives) the term takes per instance."""
        return self.term.k

    def __call__(self, X: torch.Tensor, times: torch.Tensor, params: list[torch.Tensor]) -> torch.Tensor:
        n = times.shape[0]
        out = self.fn(*X.unbind(0), times, *params)
        if not isinstance(out, torch.Tensor):
            return torch.full((n,), float(out), dtype=times.dtype, device=times.device)
        if out.dtype != times.dtype:
            out = out.to(times.dtype)
        return out.expand(n) if out.shape != (n,) else out


_CACHE: dict[int, LoweredTerm] = {}


def lower(term: CompiledTerm) -> LoweredTerm:
    """The torch function of ``term`` (cached per compiled term, which the core itself caches)."""
    cached = _CACHE.get(id(term))
    if cached is not None and cached.term is term:
        return cached
    index = {var: i for i, var in enumerate(term.variables)}
    params = {name: i for i, name in enumerate(term.parameters)}
    v_syms = [sp.Symbol(f"_v{i}") for i in range(term.k)]
    p_syms = [sp.Symbol(f"_p{i}") for i in range(len(term.parameters))]
    t_sym = sp.Symbol("_t")
    rename = {}
    for symbol in term.expr.free_symbols:
        if symbol == TIME:
            rename[symbol] = t_sym
            continue
        name, order = split_dof_symbol(symbol)
        var = LocalVar(name, order)
        if var in index:
            rename[symbol] = v_syms[index[var]]
        elif name in params and order == 0:
            rename[symbol] = p_syms[params[name]]
        else:  # compile_term guarantees this never happens
            raise ValueError(f"symbol {symbol} of term {term.expr} is neither variable nor constant")
    expr = _fold_numbers(term.expr.xreplace(rename))   # term.expr is always a sympy object
    fn = sp.lambdify([*v_syms, t_sym, *p_syms], expr, modules=[_OVERRIDES, "torch"], cse=True)
    lowered = LoweredTerm(term, fn)
    _CACHE[id(term)] = lowered
    return lowered
