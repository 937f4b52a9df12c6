"""A window problem as CasADi expressions: IPOPT evaluates it with CasADi's own AD and virtual
machine, with no Python call per evaluation.

The free control points ``s`` are the NLP's variables; the slot values (every term variable at
every instance) are ``Pf s + v0``, ``Pf`` the problem's basis rows over the free columns as a
sparse constant and ``v0`` what the fixed control points contribute, the NLP's parameter (so a
later `iterate` on the same structure, with other control points outside the window, reuses the
solver). Each group's term is lowered once to an SX function of (its variables, t, its
constants) (lowering.py) and called on the group's instances at once (``Function.map``); its
constants' values and instance times are constants of the graph (a window problem of other
constants is another structure, WindowProblem.of). The objective is ``Σ w e²`` over the squared
objective rows and ``Σ w e`` over linear ones (``maximize``/``minimize``, where the problem has
them), the constraints ``w c`` on the rows whose `when` held at the start, equalities first.

The graph is SX (scalar expressions inlined: the cheapest evaluation, what a CasADi user writes
by hand) while it has at most :data:`SX_NODES` nodes, else MX with one mapped call per group (an
arm's equations of motion at hundreds of instances would inline into millions of nodes, slow to
differentiate).
"""

from __future__ import annotations

import casadi
import numpy as np
import scipy.sparse as sps

from stw_tui.sym.kinds import TermKind

from .lowering import Unsupported, term_function

EQ, GE, OBJ = TermKind.EQ, TermKind.GE, TermKind.OBJ
SX_NODES = 200_000   # instances x term size up to which the graph is inlined as SX


def sparse_dm(matrix) -> casadi.DM:
    """A scipy sparse matrix as a CasADi sparse DM (explicit zeros kept as structure)."""
    m = sps.csc_array(matrix)
    m.sort_indices()
    sparsity = casadi.Sparsity(m.shape[0], m.shape[1], m.indptr.tolist(), m.indices.tolist())
    return casadi.DM(sparsity, np.asarray(m.data, float))


class NativeNLP:
    """The NLP ``{x, p, f, g}`` of a window problem restricted to the given live rows.

    Raises:
        Unsupported: a term the lowering does not know (lowering.py).
    """

    def __init__(self, problem, eq_rows: np.ndarray, ge_rows: np.ndarray, graph: str = "auto"):
        functions = [term_function(group.term) for group in problem.groups]   # Unsupported first
        size = sum(int(f.n_nodes()) * group.n for f, group in zip(functions, problem.groups))
        self.graph = graph if graph != "auto" else ("SX" if size <= SX_NODES else "MX")
        kind = casadi.SX if self.graph == "SX" else casadi.MX
        n = problem.n_free
        self.x = kind.sym("s", n)
        self.p = kind.sym("v0", problem.n_slots)
        v = casadi.mtimes(sparse_dm(problem.Pf), self.x) + self.p
        rows = {EQ: [], GE: []}
        objective = []
        for f, group in zip(functions, problem.groups):
            e = self._values(f, group, v)
            w = casadi.DM(np.asarray(group.weights, float))
            if group.kind == OBJ:
                objective.append(casadi.dot(w, e if getattr(group, "linear", False) else e * e))
            else:
                rows[group.kind].append(w * e)
        self.f = casadi.sum1(casadi.vertcat(*objective)) if objective else kind(1, 1)
        eq = casadi.vertcat(*rows[EQ]) if rows[EQ] else kind(0, 1)
        ge = casadi.vertcat(*rows[GE]) if rows[GE] else kind(0, 1)
        self.g = casadi.vertcat(eq[eq_rows.tolist(), 0] if eq_rows.size else kind(0, 1),
                                ge[ge_rows.tolist(), 0] if ge_rows.size else kind(0, 1))

    @staticmethod
    def _values(f: casadi.Function, group, v):
        """The group's term at its instances, a column, from the slot values ``v``."""
        n, k = group.n, group.term.k
        start = group.slot_offset
        x = casadi.reshape(v[start:start + k * n], n, k).T          # slot a*n + i: column i
        t = casadi.DM(np.asarray(group.times, float)).T
        params = np.asarray(group.params, float).reshape(-1, 1)
        p = casadi.DM(np.repeat(params, n, axis=1)) if params.size else casadi.DM(0, n)
        return f.map(n)(x, t, p).T

    def nlp(self) -> dict:
        """The ``nlpsol`` problem dictionary."""
        return {"x": self.x, "p": self.p, "f": self.f, "g": self.g}


def fixed_slot_values(problem) -> np.ndarray:
    """``v0``: the slot values with every free control point at zero (what the fixed ones give)."""
    return np.asarray(problem.P @ problem.scatter(np.zeros(problem.n_free)), float).ravel()


__all__ = ["NativeNLP", "Unsupported", "fixed_slot_values", "sparse_dm", "SX_NODES"]
