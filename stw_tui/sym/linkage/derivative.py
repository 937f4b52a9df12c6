"""Total time derivative by the chain rule, with DOF derivatives as separate symbols."""

from __future__ import annotations

from collections.abc import Iterable

import sympy as sp

from stw_tui.sym.errors import StwError
from stw_tui.sym.symbols import TIME, dof_symbol


def time_derivative(expr: sp.Expr, dof_names: Iterable[str]) -> sp.Expr:
    """d/dt of ``expr``: sum of dexpr/dq q' + dexpr/dq' q'' over the DOF, plus dexpr/dt.

    Raises :class:`StwError` if ``expr`` holds a second derivative ``q''`` (its derivative, a third
    derivative, has no symbol).
    """
    if isinstance(expr, (int, float)):
        return sp.S.Zero
    free = expr.free_symbols
    total = sp.S.Zero
    for name in dof_names:
        q, qd, qdd = dof_symbol(name), dof_symbol(name, 1), dof_symbol(name, 2)
        if qdd in free:
            raise StwError(f"cannot differentiate {name}'' in time: third derivatives have no symbol")
        if q in free:
            total += sp.diff(expr, q) * qd
        if qd in free:
            total += sp.diff(expr, qd) * qdd
    if TIME in free:
        total += sp.diff(expr, TIME)
    return total
