"""Naming of the sympy symbols every part of stw shares.

A DOF named ``x`` appears in expressions as three independent symbols: its value ``x``, its
velocity ``x'`` and its acceleration ``x''``. Time is ``t``. Constants, subexpressions and derived
linkage quantities are plain symbols named as the user names them (``g``, ``f``, ``arm.tip.x``).
"""

from __future__ import annotations

from functools import lru_cache

import sympy as sp

TIME = sp.Symbol("t", real=True)
MAX_ORDER = 2


@lru_cache(maxsize=4096)   # sympy returns the same Symbol anyway; building the key took 5 µs a call
def dof_symbol(name: str, order: int = 0) -> sp.Symbol:
    """The symbol of DOF ``name`` differentiated ``order`` (0, 1, 2) times in time."""
    if order not in (0, 1, 2):
        raise ValueError(f"derivative order must be 0, 1 or 2, not {order}")
    return sp.Symbol(name + "'" * order, real=True)


def dof_symbols(name: str) -> tuple[sp.Symbol, sp.Symbol, sp.Symbol]:
    """(value, velocity, acceleration) symbols of DOF ``name``."""
    return dof_symbol(name, 0), dof_symbol(name, 1), dof_symbol(name, 2)


def split_dof_symbol(symbol: sp.Symbol) -> tuple[str, int]:
    """Inverse of :func:`dof_symbol`: ``x''`` -> ("x", 2)."""
    name = symbol.name
    base = name.rstrip("'")
    return base, len(name) - len(base)


def named_symbol(name: str) -> sp.Symbol:
    """Symbol of a constant, subexpression or derived quantity."""
    return sp.Symbol(name, real=True)
