"""A window problem as CasADi expressions: IPOPT evaluates it with CasADi's own AD and virtual
machine, with no Python call per evaluation.

The free control points ``s`` are the NLP's variables; the slot values (every term variable at
every instance) are ``v = Pf s + v0``, ``Pf`` the problem's basis rows over the free columns as a
sparse constant and ``v0`` what the fixed control points contribute, the NLP's parameter (so a
later `iterate` on the same structure, with other control points outside the window, reuses the
solver). Each group's term is lowered once to an SX function of (its variables, t, its
constants) (lowering.py), differentiated there by CasADi in its few local variables (value,
gradient, the Hessian's structurally nonzero upper entries: :func:`local_derivatives`), and
called on the group's instances at once (``Function.map``); its constants' values and instance
times are constants of the graph (a window problem of other constants is another structure,
WindowProblem.of).

The objective is ``Σ w e²`` over the squared objective rows and ``Σ w e`` over linear ones
(``maximize``/``minimize``, where the problem has them), the constraints ``w c`` on the rows whose
`when` held at the start, equalities first. Their derivatives are assembled by the chain rule,
as stw's own evaluation does (window.py), in CasADi: the gradient ``Pfᵀ (∂R/∂v)``, the Jacobian
``G Pf`` with ``G`` the rows' local gradients, and the Lagrangian's Hessian ``Pfᵀ D Pf`` with ``D``
block diagonal over instances: ``σ 2w (e ∇²e + ∇e ∇eᵀ)`` for a squared objective row,
``σ w ∇²e`` for a linear one, ``λ w ∇²c`` for a constraint row. CasADi's AD of the whole graph
(reverse over the 4 control points of every variable at every instance) made an arm's Hessian
1.5 million instructions and took 2 s to build; from the local derivatives it is a small
fraction of that.

The graph is SX (scalar expressions inlined: the cheapest evaluation, what a CasADi user writes
by hand) while its second derivatives take at most :data:`SX_INSTRUCTIONS` instructions (the
instances times their local function's: :func:`instructions`), else MX with one mapped call per
group: building an SX solver costs about 6 µs an instruction (0.4 s for cartpole, 6 s for luxo),
an MX one a fifth of that, and an MX iteration 1.3-1.6 times an SX one.
"""

from __future__ import annotations

import threading
import weakref

import casadi
import numpy as np
import scipy.sparse as sps

from stw_tui.sym.kinds import TermKind

from .lowering import Unsupported, term_function

EQ, GE, OBJ = TermKind.EQ, TermKind.GE, TermKind.OBJ
SX_INSTRUCTIONS = 100_000   # second-derivative instructions up to which the graph is inlined as SX
_LOCAL: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # term -> (functions, pairs)
_LOCAL_LOCK = threading.Lock()


def sparse_dm(matrix) -> casadi.DM:
    """A scipy sparse matrix as a CasADi sparse DM (explicit zeros kept as structure)."""
    m = sps.csc_array(matrix)
    m.sort_indices()
    sparsity = casadi.Sparsity(m.shape[0], m.shape[1], m.indptr.tolist(), m.indices.tolist())
    return casadi.DM(sparsity, np.asarray(m.data, float))


def local_derivatives(term) -> tuple[tuple[casadi.Function, ...], list[tuple[int, int]]]:
    """``term`` as three functions of ``(x, t, p)``: its value ``e``; ``(e, ∇e)``; and
    ``(e, ∇e, h)``, with its gradient in its ``k`` variables and ``h`` the structurally nonzero
    entries of its Hessian's upper triangle, at ``pairs`` (a <= b). Three, because a mapped MX
    call computes every output of its function: the objective's evaluation must not pay for the
    Hessian. Kept per compiled term.

    Raises:
        Unsupported: as lowering.term_function.
    """
    with _LOCAL_LOCK:
        found = _LOCAL.get(term)
    if found is None:
        f = term_function(term)
        x, t, p = (casadi.SX.sym(name, *f.size_in(i)) for i, name in enumerate(("x", "t", "p")))
        e = f(x, t, p)
        hessian, gradient = casadi.hessian(e, x)
        rows, cols = casadi.triu(hessian).sparsity().get_triplet()
        pairs = sorted(zip(rows, cols))
        h = casadi.vertcat(*[hessian[a, b] for a, b in pairs]) if pairs else casadi.SX(0, 1)
        functions = (casadi.Function("value", [x, t, p], [e]),
                     casadi.Function("first", [x, t, p], [e, gradient]),
                     casadi.Function("second", [x, t, p], [e, gradient, h]))
        found = (functions, pairs)
        with _LOCAL_LOCK:
            _LOCAL[term] = found
    return found


def instructions(problem) -> int:
    """The instructions of CasADi's virtual machine in one evaluation of every group's second
    derivatives at all its instances: what a native Hessian costs (about 8 ns each here).

    Raises:
        Unsupported: as :func:`local_derivatives`.
    """
    return sum(int(local_derivatives(group.term)[0][2].n_instructions()) * group.n
               for group in problem.groups)


def forget_local_derivatives() -> None:
    """Drop the kept local derivative functions (the next build lowers every term again)."""
    with _LOCAL_LOCK:
        _LOCAL.clear()


def _assemble(rows: np.ndarray, cols: np.ndarray, values, shape: tuple[int, int], kind):
    """A sparse ``kind`` matrix from distinct (row, col) triplets and the column of their values."""
    order = np.lexsort((rows, cols))
    colind = np.zeros(shape[1] + 1, np.int64)
    np.add.at(colind, cols + 1, 1)
    sparsity = casadi.Sparsity(shape[0], shape[1], np.cumsum(colind).tolist(), rows[order].tolist())
    if not order.size:
        return kind(sparsity)
    return kind(sparsity, values[order.tolist()])


class NativeNLP:
    """The NLP of a window problem restricted to the given live rows, with its derivatives.

    Raises:
        Unsupported: a term the lowering does not know (lowering.py).
    """

    def __init__(self, problem, eq_rows: np.ndarray, ge_rows: np.ndarray, graph: str = "auto"):
        locals_ = [local_derivatives(group.term) for group in problem.groups]   # Unsupported first
        size = instructions(problem)
        self.graph = graph if graph != "auto" else ("SX" if size <= SX_INSTRUCTIONS else "MX")
        kind = casadi.SX if self.graph == "SX" else casadi.MX
        n, n_slots = problem.n_free, problem.n_slots
        m_eq, m_ge = eq_rows.size, ge_rows.size
        self.x = kind.sym("s", n)
        self.p = kind.sym("v0", n_slots)
        self.lam_f = kind.sym("lam_f")
        self.lam_g = kind.sym("lam_g", m_eq + m_ge)
        Pf = sparse_dm(problem.Pf)
        v = casadi.mtimes(Pf, self.x) + self.p
        # live row r of a kind -> its place in g (-1: left out)
        place = {EQ: np.full(problem.row_counts[EQ], -1), GE: np.full(problem.row_counts[GE], -1)}
        place[EQ][eq_rows] = np.arange(m_eq)
        place[GE][ge_rows] = m_eq + np.arange(m_ge)
        objective, g_parts, g_rows = [], [], []
        grad_slots, grad_values = [], []          # ∂R/∂v
        jac = ([], [], [])                        # G: (g row, slot, value)
        hess = ([], [], [])                       # D: (slot, slot, value), both triangles
        for (local, pairs), group in zip(locals_, problem.groups):
            k, m = group.term.k, group.n
            slots = group.slot_offset + np.arange(k * m).reshape(k, m)    # slot of (a, i)
            inputs = self._inputs(group, v)
            e0 = local[0].map(m)(*inputs)                                  # 1 x m: for f and g
            e1, grad1 = local[1].map(m)(*inputs)                           # for ∇f and the Jacobian
            e, grad, h = local[2].map(m)(*inputs)                          # for the Hessian
            w = casadi.DM(np.asarray(group.weights, float)).T             # 1 x m
            if group.kind == OBJ:
                linear = group.linear
                objective.append(casadi.sum2(w * (e0 if linear else e0 * e0)))
                grad_slots.append(slots.ravel())
                scale1 = w if linear else 2 * w * e1                      # ∂R/∂e per instance
                grad_values.append(casadi.reshape((grad1 * casadi.repmat(scale1, k, 1)).T, -1, 1))
                scale = w if linear else 2 * w * e
                # D: σ (scale ∇²e + [2w ∇e ∇eᵀ]); every pair for a squared row (Gauss-Newton)
                full = [(a, b) for a in range(k) for b in range(a, k)] if not linear else pairs
                known = {pair: i for i, pair in enumerate(pairs)}
                for a, b in full:
                    value = 0
                    if (a, b) in known:
                        value = scale * h[known[a, b], :]
                    if not linear:
                        value = value + 2 * w * grad[a, :] * grad[b, :]
                    self._pair(hess, slots, a, b, self.lam_f * value)
                continue
            rows = place[group.kind][group.row_offset + np.arange(m)]
            live = np.flatnonzero(rows >= 0)
            g_parts.append((w * e0)[0, live.tolist()])
            g_rows.append(rows[live])
            if not live.size:
                continue
            wl = w[0, live.tolist()]
            for a in range(k):
                jac[0].append(rows[live])
                jac[1].append(slots[a, live])
                jac[2].append(casadi.reshape(wl * grad1[a, live.tolist()], -1, 1))
            lam = self.lam_g[rows[live].tolist()].T                       # 1 x live
            for index, (a, b) in enumerate(pairs):
                self._pair(hess, slots[:, live], a, b, lam * wl * h[index, live.tolist()])
        self.f = casadi.sum1(casadi.vertcat(*objective)) if objective else kind(1, 1)
        order = np.argsort(np.concatenate(g_rows)) if g_rows else np.zeros(0, int)
        g_all = casadi.horzcat(*g_parts).T if g_parts else kind(0, 1)
        self.g = g_all[order.tolist(), 0] if order.size else kind(0, 1)
        grad_v = _assemble(np.concatenate(grad_slots) if grad_slots else np.zeros(0, int),
                           np.zeros(sum(s.size for s in grad_slots), int),
                           casadi.vertcat(*grad_values) if grad_values else kind(0, 1), (n_slots, 1), kind)
        # dense: IPOPT read garbage from a sparse gradient of an SX function (entries of control
        # points outside the objective), and took a different path at every solve
        self.grad_f = casadi.densify(casadi.mtimes(Pf.T, grad_v))
        G = _assemble(_cat(jac[0]), _cat(jac[1]), casadi.vertcat(*jac[2]) if jac[2] else kind(0, 1),
                      (m_eq + m_ge, n_slots), kind)
        self.jac_g = casadi.mtimes(G, Pf)
        D = _assemble(_cat(hess[0]), _cat(hess[1]), casadi.vertcat(*hess[2]) if hess[2] else kind(0, 1),
                      (n_slots, n_slots), kind)
        self.hess_lag = casadi.triu(casadi.mtimes(Pf.T, casadi.mtimes(D, Pf)))

    @staticmethod
    def _inputs(group, v) -> tuple:
        """The arguments of a group's local functions mapped over its instances: its variables'
        slot values (k x n, from ``v``), its times (1 x n) and its constants (np x n)."""
        n, k = group.n, group.term.k
        start = group.slot_offset
        x = casadi.reshape(v[start:start + k * n], n, k).T          # slot a*n + i: column i
        t = casadi.DM(np.asarray(group.times, float)).T
        params = np.asarray(group.params, float).reshape(-1, 1)
        p = casadi.DM(np.repeat(params, n, axis=1)) if params.size else casadi.DM(0, n)
        return x, t, p

    @staticmethod
    def _pair(hess, slots: np.ndarray, a: int, b: int, value) -> None:
        """D's entries of variables (a, b) at the instances of ``slots`` (and (b, a) off the diagonal)."""
        column = casadi.reshape(value, -1, 1)
        hess[0].append(slots[a]), hess[1].append(slots[b]), hess[2].append(column)
        if a != b:
            hess[0].append(slots[b]), hess[1].append(slots[a]), hess[2].append(column)

    def nlp(self) -> dict:
        """The ``nlpsol`` problem dictionary."""
        return {"x": self.x, "p": self.p, "f": self.f, "g": self.g}

    def derivative_options(self, function_options: dict | None = None) -> dict:
        """``nlpsol`` options handing IPOPT these derivatives instead of CasADi's AD of f and g
        (``function_options``: of each of those functions, say CasADi's ``jit``)."""
        x, p, opts = self.x, self.p, function_options or {}
        return {"grad_f": casadi.Function("grad_f", [x, p], [self.f, self.grad_f], opts),
                "jac_g": casadi.Function("jac_g", [x, p], [self.g, self.jac_g], opts),
                "hess_lag": casadi.Function("hess_lag", [x, p, self.lam_f, self.lam_g], [self.hess_lag], opts)}


def _cat(parts: list) -> np.ndarray:
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


def fixed_slot_values(problem) -> np.ndarray:
    """``v0``: the slot values with every free control point at zero (what the fixed ones give)."""
    return np.asarray(problem.P @ problem.scatter(np.zeros(problem.n_free)), float).ravel()


__all__ = ["NativeNLP", "Unsupported", "fixed_slot_values", "forget_local_derivatives", "local_derivatives",
           "instructions", "sparse_dm", "SX_INSTRUCTIONS"]
