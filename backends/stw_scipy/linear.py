"""SciPy sparse linear algebra for the shared SQP: the symmetric indefinite KKT system

    K = [[H, Aᵀ], [A, -diag(e)]]        K [d; λ] = [-g; -c]

``direct`` factorizes K once (SuperLU) and re-solves cheaply, which the interior-point method and
the line search's second-order correction use. ``cg`` is the paper's route: conjugate gradients
on the least-squares (normal equation) form KᵀK x = Kᵀb, which is symmetric positive definite even
though K is indefinite. ``minres`` works on K directly (K is symmetric). An iterative solve whose
residual is not small enough is replaced by a factorization (counted as a fallback).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from stw_tui.sos.compressed import add, csc, csr, same_structure, structure, transpose
from stw_tui.sos.products import GramPlan
from stw_tui.sos.sparse_matvec import matvec
from stw_tui.sos.sqp.algebra import KKTSystem, LinearAlgebra, SingularSystem
from stw_scipy.banded import BAND_MAX, CholeskyBandPlan
from stw_scipy.csr_rows import select_rows, stack_rows
from stw_scipy.ordering import Ordering, factorize
from stw_scipy.vectors import NumpyVectors

SOLVERS = ("direct", "minres", "cg")
FALLBACK_RESIDUAL = 1e-6   # relative KKT residual above which an iterative solve is not trusted
DENSE_TEST_MAX = 300       # rows up to which the positive-definiteness test is a dense Cholesky


def kkt_matrix(H, A, e, layouts: list | None = None) -> sps.csc_array:
    """K = [[H, Aᵀ], [A, -diag(e)]] in CSC, entry for entry what ``sps.block_array`` builds (its
    stored zeros kept, zeros of ``e`` left out, row indices sorted), without its conversions
    through COO, which cost more than factorizing K.

    Where K's entries go depends only on the sparsity structure of H and A (and on which e_i are
    zero): that placement is worked out once and kept in ``layouts`` (most recent first), so a
    later K of the same structure is one gather of its values.
    """
    m = A.shape[0]
    if not m:
        return _canonical(sps.csc_array(H))
    H, A = _csr(H), _csr(A)
    e = np.asarray(e, float)   # a scalar e (the QP's): np.full, np.broadcast_to costs more than K's gather
    diag = np.full(m, -e) if e.ndim == 0 else -np.broadcast_to(e, (m,))
    keep = diag != 0
    layouts = [] if layouts is None else layouts
    layout = next((x for x in layouts if x.fits(H, A, keep)), None)
    if layout is None:
        layout = _Layout(H, A, keep)
        if layout.repeats:   # block_array sums repeated entries: sum them first
            H, A = _canonical(H), _canonical(A)
            layout = next((x for x in layouts if x.fits(H, A, keep)), None) or _Layout(H, A, keep)
    if layout in layouts:
        layouts.remove(layout)
    layouts.insert(0, layout)
    del layouts[LAYOUTS_KEPT:]
    h, a = H.data[:H.nnz], A.data[:A.nnz]
    data = np.concatenate([h, a, a, diag[keep]])[layout.order]
    K = csc(data, layout.indices, layout.indptr, layout.shape)
    K.has_canonical_format = True   # sorted, no duplicates, by construction
    return K


LAYOUTS_KEPT = 8   # KKT structures remembered per algebra (Newton / Gauss-Newton, working sets, correction)
GRAMS_KEPT = 4     # structures of interior-point inequality rows remembered per algebra
TRANSPOSES_KEPT = 4
PLACEMENTS_KEPT = 4   # interior-point KKT structures remembered per algebra
CHOLESKY_PLANS_KEPT = 4   # structures of positive-definiteness tests remembered per algebra


class _Layout:
    """Where the entries of H (CSR order), A, Aᵀ (both A's CSR order) and the kept -e_i go in K's
    CSC arrays, for one sparsity structure of H and A (each row's entries in any order, but none
    stored twice: ``repeats`` says so)."""

    def __init__(self, H: sps.csr_array, A: sps.csr_array, keep: np.ndarray):
        n, m = H.shape[0], A.shape[0]
        h_idx, a_idx = H.indices[:H.nnz], A.indices[:A.nnz]
        self.key = (H.shape, A.shape, H.indptr.copy(), h_idx.copy(), A.indptr.copy(),
                    a_idx.copy(), keep.copy())
        h_rows = np.repeat(np.arange(n), np.diff(H.indptr))
        a_rows = np.repeat(np.arange(m), np.diff(A.indptr))
        e_rows = n + np.flatnonzero(keep)
        rows = np.concatenate([h_rows, n + a_rows, a_idx, e_rows])
        cols = np.concatenate([h_idx, a_idx, n + a_rows, e_rows])
        self.order = np.lexsort((rows, cols))          # column-major, rows sorted in each column
        same = (np.diff(rows[self.order]) == 0) & (np.diff(cols[self.order]) == 0)
        self.repeats = bool(same.any())                 # an entry stored twice (not canonical)
        self.indices = rows[self.order].astype(np.intc)   # SuperLU's index type
        self.indptr = np.zeros(n + m + 1, dtype=np.intc)
        np.cumsum(np.bincount(cols, minlength=n + m), out=self.indptr[1:])
        self.shape = (n + m, n + m)

    def fits(self, H: sps.csr_array, A: sps.csr_array, keep: np.ndarray) -> bool:
        shape_h, shape_a, h_ptr, h_idx, a_ptr, a_idx, kept = self.key
        return (H.shape == shape_h and A.shape == shape_a and H.nnz == h_idx.size
                and A.nnz == a_idx.size and np.array_equal(keep, kept)
                and np.array_equal(H.indptr, h_ptr) and np.array_equal(A.indptr, a_ptr)
                and np.array_equal(H.indices[:H.nnz], h_idx) and np.array_equal(A.indices[:A.nnz], a_idx))


class BarrierKKT:
    """The interior-point systems of one QP, K(q, e) = [[H + Aᵢᵀ diag(q) Aᵢ, Aₑᵀ], [Aₑ, -diag(e)]],
    each bit for bit what ``kkt_matrix(H + gram(Aᵢ, q), Aₑ, e)`` builds.

    H, Aᵢ and Aₑ stay fixed while the method runs: K is their values, kept in place, plus the
    Gram values scattered into a structure placed once (:class:`_BarrierPlacement`, kept per
    structure of H, Aᵢ and Aₑ), instead of two sparse sums, a zero-dropping pass and a layout
    search per iteration. Scipy's sum drops an entry of H + Gram that comes out exactly zero, and
    SuperLU's ordering would see the difference: such a K (or one with a zero e_i, which
    kkt_matrix leaves out) is assembled the general way.
    """

    def __init__(self, algebra: "SparseAlgebra", H, Ai, Ae):
        self.algebra, self.H, self.Ai, self.Ae = algebra, _csr(H), _csr(Ai), _csr(Ae)
        self.plan = algebra.gram_plan(self.Ai)
        self.placed = algebra.barrier_placement(self.H, self.plan, self.Ae)
        self.ordering = None   # SuperLU's replayed ordering of the placed structure, once known
        if self.placed is not None:
            self.base = self.placed.values(self.H, self.Ae)

    def __call__(self, q: np.ndarray, e) -> "SparseKKT":
        la, placed = self.algebra, self.placed
        diag = np.asarray(e, float)
        if diag.shape != (self.Ae.shape[0],):   # a scalar e (np.broadcast_to costs more than K's gather)
            diag = np.broadcast_to(diag, (self.Ae.shape[0],))
        if placed is not None and diag.all():
            data = self.base.copy()
            data[placed.at_g] += self.plan.values(self.Ai.data[:self.Ai.nnz], np.asarray(q, float))
            if data[placed.at_s].all():
                data[placed.at_e] = -diag
                if self.ordering is not None:   # the structure's ordering, found at the first K
                    return ReplayedKKT(self.ordering, placed, data)
                K = sps.csc_array((data, placed.indices, placed.indptr), shape=placed.shape)
                K.has_canonical_format = True
                system = SparseKKT(K, "direct", la.rtol, la.maxiter, la._orderings, la.band_max)
                self.ordering = next((o for o in la._orderings if o.fits(K, "COLAMD", {})), None)
                return system
        return la.kkt(la.add(self.H, la.gram(self.Ai, q)), self.Ae, e, exact=True)


class _BarrierPlacement:
    """Where the entries of H, of a Gram plan's structure and of Aₑ (as A and Aᵀ) and the
    diagonal go in the CSC arrays of K = [[H + Gram, Aₑᵀ], [Aₑ, -diag(e)]], for one structure of
    each; None from :meth:`of` when H or Aₑ stores an entry twice (kkt_matrix would sum them)."""

    @classmethod
    def of(cls, H: sps.csr_array, plan: GramPlan, Ae: sps.csr_array) -> "_BarrierPlacement | None":
        n, m = H.shape[0], Ae.shape[0]
        h_key = np.repeat(np.arange(n, dtype=np.int64), np.diff(H.indptr)) * n + H.indices[:H.nnz]
        g_key = np.repeat(np.arange(n, dtype=np.int64), np.diff(plan.indptr)) * n + plan.indices
        keys = np.concatenate([h_key, g_key])
        order = np.argsort(keys, kind="stable")
        first = np.diff(keys[order], prepend=-1) != 0     # the sum's entries, sorted
        group = np.empty(keys.size, dtype=np.intp)
        group[order] = np.cumsum(first) - 1
        if np.bincount(group[:h_key.size]).max(initial=0) > 1:
            return None                                   # H stores an entry twice
        union = keys[order][first]
        indptr = np.zeros(n + 1, dtype=np.intc)
        np.cumsum(np.bincount(union // n, minlength=n), out=indptr[1:])
        S = sps.csr_array((np.ones(union.size), (union % n).astype(np.intc), indptr), shape=(n, n))
        layout = _Layout(S, Ae, np.ones(m, bool))
        if layout.repeats:                                # Aₑ stores an entry twice
            return None
        placed = cls()
        at = np.empty(layout.order.size, dtype=np.intp)   # where each of K's sources lands
        at[layout.order] = np.arange(layout.order.size)
        placed.at_s, placed.at_a, placed.at_e = np.split(at, [union.size, union.size + 2 * Ae.nnz])
        placed.at_h, placed.at_g = placed.at_s[group[:h_key.size]], placed.at_s[group[h_key.size:]]
        placed.indices, placed.indptr, placed.shape = layout.indices, layout.indptr, layout.shape
        placed.key = (structure(H), structure(plan), structure(Ae))
        return placed

    def fits(self, H: sps.csr_array, plan: GramPlan, Ae: sps.csr_array) -> bool:
        return all(same_structure(m, key) for m, key in zip((H, plan, Ae), self.key))

    def values(self, H: sps.csr_array, Ae: sps.csr_array) -> np.ndarray:
        """K's data with H's and Aₑ's values in place, zeros where the Gram values and -e go."""
        data = np.zeros(self.at_s.size + self.at_a.size + self.at_e.size)
        a = Ae.data[:Ae.nnz]
        data[self.at_a] = np.concatenate([a, a])
        data[self.at_h] = H.data[:H.nnz]
        return data


class _WorkingSetLayout:
    """Where the entries of K = [[H, Aᵀ], [A, -e I]] go for every working set of one structure of
    H, Aₑ and Aᵢ (A: Aₑ's rows and the binding ones of Aᵢ): the layout of K with all of Aᵢ's rows,
    of which a working set's K is the masked copy, entry for entry what kkt_matrix builds (its
    rows and columns are a subset, relabelled in order, and each column's rows stay sorted).
    None from :meth:`of` when H or a row of A stores an entry twice (kkt_matrix would sum them)."""

    @classmethod
    def of(cls, H: sps.csr_array, Ae: sps.csr_array, Ai: sps.csr_array) -> "_WorkingSetLayout | None":
        A = stack_rows([Ae, Ai])
        layout = _Layout(H, A, np.ones(A.shape[0], bool))
        if layout.repeats:
            return None
        placed = cls()
        placed.layout, placed.fixed = layout, H.shape[0] + Ae.shape[0]   # rows every set keeps
        placed.columns = np.repeat(np.arange(layout.shape[0]), np.diff(layout.indptr))
        placed.key = (structure(H), structure(Ae), structure(Ai))
        return placed

    def fits(self, H: sps.csr_array, Ae: sps.csr_array, Ai: sps.csr_array) -> bool:
        return all(same_structure(m, key) for m, key in zip((H, Ae, Ai), self.key))


class WorkingSetKKT:
    """The working-set systems of one QP (LinearAlgebra.working_set_kkt): K's values with every
    row of Aᵢ placed once, and per working set the masked copy of the kept rows and columns,
    instead of stacking the rows and working out K's layout anew for each new set (most of a
    trial's cost before its factorization: 0.25 of 0.55 ms on the arm, 0.6 of 2.6 on basketball)."""

    def __init__(self, algebra: "SparseAlgebra", H, Ae, Ai, e: float):
        self.algebra, self.H, self.Ae, self.Ai, self.e = algebra, _csr(H), _csr(Ae), _csr(Ai), float(e)
        self.placed = algebra.working_set_layout(self.H, self.Ae, self.Ai) if self.e != 0 else None
        if self.placed is not None:
            m = self.Ae.shape[0] + self.Ai.shape[0]
            a = np.concatenate([self.Ae.data[:self.Ae.nnz], self.Ai.data[:self.Ai.nnz]])
            self.values = np.concatenate([self.H.data[:self.H.nnz], a, a, np.full(m, -self.e)])[self.placed.layout.order]

    def __call__(self, binding: np.ndarray) -> "SparseKKT":
        la, placed = self.algebra, self.placed
        if placed is None:   # e = 0 (kkt_matrix leaves the diagonal out) or repeated entries
            return LinearAlgebra.working_set_kkt(la, self.H, self.Ae, self.Ai, self.e)(binding)
        layout = placed.layout
        kept = np.concatenate([np.ones(placed.fixed, bool), binding])
        entries = kept[layout.indices] & kept[placed.columns]
        label = np.cumsum(kept, dtype=np.intc) - 1                 # a kept row's (column's) new number
        size = int(label[-1]) + 1 if label.size else 0
        indptr = np.zeros(size + 1, dtype=np.intc)
        np.cumsum(np.bincount(placed.columns[entries], minlength=kept.size)[kept], out=indptr[1:])
        K = csc(self.values[entries], label[layout.indices[entries]], indptr, (size, size))
        K.has_canonical_format = True   # sorted, no duplicates, as kkt_matrix's
        return SparseKKT(K, "direct", la.rtol, la.maxiter, la._orderings, la.band_max)


def _kept_by_structure(kept: list, m, make, limit: int):
    """``make(m)``, or what it made for an earlier array of ``m``'s structure: ``kept`` holds the
    last ``limit`` (structure, made) pairs, newest first (a None made is remembered too)."""
    for key, made in kept:
        if same_structure(m, key):
            return made
    made = make(m)
    kept.insert(0, (structure(m), made))
    del kept[limit:]
    return made


def _recent(kept: list, fits, make, limit: int = PLACEMENTS_KEPT):
    """The newest of ``kept`` that ``fits``, moved to the front; else ``make()``, put in front
    (the last ``limit`` kept) unless it is None."""
    for i, placed in enumerate(kept):
        if fits(placed):
            kept.insert(0, kept.pop(i))
            return placed
    placed = make()
    if placed is not None:
        kept.insert(0, placed)
        del kept[limit:]
    return placed


def _csr(m) -> sps.csr_array:
    return m if isinstance(m, sps.csr_array) else sps.csr_array(m)


def _canonical(m):
    """``m`` with sorted indices and no duplicates (as block_array's conversion leaves them)."""
    if not m.has_canonical_format:
        m = m.copy()
        m.sum_duplicates()
    return m


class SparseKKT(KKTSystem):
    """K solved by a factorization (``direct``) or by MINRES / CG with a factorization as
    fallback; with ``orderings`` (ordering.py), SuperLU's column ordering of K's structure is
    replayed, and with ``band_max`` a K that is a band that narrow is factorized banded instead."""

    def __init__(self, K: sps.csc_array, method: str, rtol: float, maxiter: int,
                 orderings: list | None = None, band_max: int = 0):
        self.K, self.method, self.rtol, self.maxiter = K, method, rtol, maxiter
        self.orderings, self.band_max = orderings, band_max
        self.iterations = self.fallbacks = 0
        self._lu = None
        if method == "direct":
            self._factorize()

    def _factorize(self):
        if self._lu is None:
            try:
                self._lu = factorize(self.K, self.orderings, band_max=self.band_max)
            except RuntimeError as exc:   # "Factor is exactly singular"
                raise SingularSystem(str(exc)) from exc
            self.iterations += 1
        return self._lu

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self.method == "direct" or self._lu is not None:
            return self._factorize().solve(rhs)
        with np.errstate(all="ignore"):   # a diverging Krylov run is detected below, not warned about
            x = self._iterative(rhs)
        if np.all(np.isfinite(x)) and float(np.linalg.norm(self.K @ x - rhs)) <= \
                FALLBACK_RESIDUAL * max(1.0, float(np.linalg.norm(rhs))):
            return x
        # Barrier-scaled or nearly singular systems can defeat unpreconditioned Krylov methods:
        # rather than take a wrong step, factorize (and say so in the iteration report).
        self.fallbacks += 1
        return self._factorize().solve(rhs)

    def _iterative(self, b: np.ndarray) -> np.ndarray:
        count = [0]

        def tick(_):
            count[0] += 1

        K = self.K
        if self.method == "minres":
            x, _ = spla.minres(K, b, rtol=self.rtol, maxiter=self.maxiter, callback=tick)
        else:  # cg on KᵀK (K symmetric, so KᵀK = K·K) with a Jacobi preconditioner
            normal = spla.LinearOperator(K.shape, matvec=lambda v: K @ (K @ v), dtype=float)
            diag = np.asarray((K.multiply(K)).sum(axis=0)).ravel()
            precond = spla.LinearOperator(K.shape, matvec=lambda v: v / np.where(diag > 0, diag, 1.0),
                                          dtype=float)
            x, _ = spla.cg(normal, K @ b, rtol=self.rtol, maxiter=self.maxiter, M=precond, callback=tick)
        self.iterations += count[0]
        return x


class ReplayedKKT(KKTSystem):
    """A direct SparseKKT of a placed structure whose ordering is known, factorized from K's CSC
    values alone (the interior-point method's systems: same structure, new values each
    iteration); K itself is built only when asked for."""

    def __init__(self, ordering: Ordering, placed: "_BarrierPlacement", data: np.ndarray):
        try:
            self._lu = ordering.factorize_values(data)
        except RuntimeError as exc:   # "Factor is exactly singular"
            raise SingularSystem(str(exc)) from exc
        self.placed, self.data = placed, data
        self.iterations, self.fallbacks = 1, 0

    @property
    def K(self) -> sps.csc_array:
        """K itself (as SparseKKT holds it), built from the values on demand."""
        K = csc(self.data, self.placed.indices, self.placed.indptr, self.placed.shape)
        K.has_canonical_format = True
        return K

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._lu.solve(rhs)


# Each `iterate` makes a new algebra, and its window problem mostly has the last one's sparsity
# structures: the plans worked out for them (layouts, orderings, placements: 0.5 ms of the
# pendulum's 6.4 ms `iterate`) are taken over from the algebra made last with the same band
# limit (a superlu-only algebra must not meet banded plans), as copies of its lists. Every plan
# is checked against a matrix's structure before it is used, and none changes once made (an
# Ordering's scratch matrix is locked), so an abandoned, hung solve still running beside the
# next one shares nothing it could spoil.
_STRUCTURE_LISTS = ("_layouts", "_grams", "_placements", "_working_sets", "_orderings", "_cholesky_plans")
_LATEST_STRUCTURES: dict[int, dict[str, list]] = {}


def inherit_structures(algebra: "SparseAlgebra") -> None:
    """Give ``algebra`` copies of the per-structure plans of the last algebra with its band
    limit, and make its own lists the ones the next algebra copies."""
    last = _LATEST_STRUCTURES.get(algebra.band_max, {})
    for name in _STRUCTURE_LISTS:
        setattr(algebra, name, list(last.get(name, ())))   # one C-level copy: atomic under the GIL
    _LATEST_STRUCTURES[algebra.band_max] = {name: getattr(algebra, name) for name in _STRUCTURE_LISTS}


class SparseAlgebra(NumpyVectors):
    """numpy vectors, scipy sparse (CSR) matrices, KKT systems by banded LU or SuperLU, MINRES
    or CG."""

    def __init__(self, method: str = "direct", rtol: float = 1e-12, maxiter: int = 1000,
                 factor: str = "auto"):
        self.method, self.rtol, self.maxiter = method, rtol, maxiter
        # direct factorizations: banded LU where a KKT's band is narrow (banded.py), else SuperLU
        self.band_max = BAND_MAX if factor == "auto" else 0
        self._transposes: list = []   # (matrix, its transpose) of recent rmatvec() calls
        # What is worked out per sparsity structure, most recent first, from the last algebra's:
        # self._layouts        KKT placements (kkt_matrix)
        # self._grams          (structure, GramPlan) of recent gram() factors
        # self._placements     interior-point KKT placements (BarrierKKT)
        # self._working_sets   working-set KKT layouts (WorkingSetKKT)
        # self._orderings      SuperLU column orderings and banded plans by KKT structure (ordering.py)
        # self._cholesky_plans (structure, banded test or None: too wide) (banded.py)
        inherit_structures(self)

    def matrix(self, m):
        return m if isinstance(m, sps.csr_array) else sps.csr_array(m)

    def diagonal_matrix(self, v):
        # What diags_array(v, format="csr") builds (its zeros left out), without its conversions.
        v = np.asarray(v, float)
        at = np.flatnonzero(v)
        indptr = np.zeros(v.size + 1, dtype=np.int32)
        np.cumsum(v != 0, out=indptr[1:])
        return csr(v[at], at.astype(np.int32), indptr, (v.size, v.size))

    def rows(self, m, index):
        if index.size == m.shape[0] and np.array_equal(index, np.arange(index.size)):
            return m   # every row, in order: m[index] would copy m as it is
        return select_rows(m, index) if isinstance(m, sps.csr_array) else m[index]

    def stack_rows(self, parts):
        if all(isinstance(p, sps.csr_array) for p in parts):
            return stack_rows(parts)
        return sps.vstack(parts, format="csr")

    def matvec(self, m, x):
        return matvec(m, x)

    def rmatvec(self, m, x):
        # The interior-point method multiplies by the same few transposes many times: keep them.
        for held, transposed in self._transposes:
            if held is m:
                return matvec(transposed, x)
        self._transposes.insert(0, (m, transpose(m)))
        del self._transposes[TRANSPOSES_KEPT:]
        return matvec(self._transposes[0][1], x)

    def add(self, a, b):
        return _csr(add(a, b))

    def gram(self, a, w):
        # sps.csr_array(a.T @ (sps.diags_array(w) @ a)), bitwise, by a plan kept per structure of a
        a = _csr(a)
        return self.gram_plan(a).matrix(a.data[:a.nnz], np.asarray(w, float))

    def gram_plan(self, a: sps.csr_array) -> GramPlan:
        """The Gram plan of ``a``'s structure (made once, kept for the next few structures)."""
        return _kept_by_structure(self._grams, a, GramPlan, GRAMS_KEPT)

    def barrier_kkt(self, H, Ai, Ae):
        return BarrierKKT(self, H, Ai, Ae)

    def working_set_kkt(self, H, Ae, Ai, e):
        return WorkingSetKKT(self, H, Ae, Ai, e)

    def working_set_layout(self, H, Ae, Ai) -> _WorkingSetLayout | None:
        """The working-set layout of these structures (worked out once, the last few kept)."""
        return _recent(self._working_sets, lambda placed: placed.fits(H, Ae, Ai),
                       lambda: _WorkingSetLayout.of(H, Ae, Ai))

    def barrier_placement(self, H, plan, Ae) -> _BarrierPlacement | None:
        """The placement of K's entries for these structures (worked out once, the last few kept)."""
        return _recent(self._placements, lambda placed: placed.fits(H, plan, Ae),
                       lambda: _BarrierPlacement.of(H, plan, Ae))

    def row_squares(self, a):
        a = _csr(a)
        return np.asarray(a.multiply(a).sum(axis=1), dtype=float).ravel()

    def max_abs_diagonal(self, m):
        return float(np.abs(m.diagonal()).max(initial=0.0))

    def positive_definite(self, m):
        if m.shape[0] <= DENSE_TEST_MAX:
            # LAPACK's Cholesky of the dense matrix (its lower triangle): at this size it costs
            # a tenth to a third of the sparse test below (pendulum, 23 rows: 29 against 339 µs;
            # arm_throw, 135 rows: 161 against 516 µs; basketball, 459 rows: 1.5 against 1.1 ms).
            # LAPACK may carry a NaN through instead of stopping: a NaN entry reaches a pivot.
            factor, info = lapack.dpotrf(m.toarray(), lower=1, overwrite_a=1, clean=0)
            return info == 0 and bool(np.isfinite(factor.diagonal()).all())
        if self.band_max:
            # LAPACK's banded Cholesky where m is a narrow band in RCM order (banded.py): on
            # basketball's 459 rows, half-width 83, 0.56 ms against the LDLᵀ's 1.2 ms, and 0.07
            # against 1.1 where it stops at an early pivot (not positive definite)
            plan = _kept_by_structure(self._cholesky_plans, m, CholeskyBandPlan.of, CHOLESKY_PLANS_KEPT)
            if plan is not None:
                return plan.positive_definite(m)
        # LDLᵀ in SuperLU's clothes: a symmetric ordering and the diagonal always taken as pivot
        # (SuperLU leaves it only for an exact zero, which perm_r != perm_c then shows). All
        # pivots positive <=> all leading minors positive <=> positive definite (Sylvester).
        # (The pivots are the same in the replay of the ordering, ordering.py, at the same places.)
        try:
            lu = factorize(sps.csc_array(m), self._orderings, "MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True}).lu
        except RuntimeError:   # an exactly zero pivot
            return False
        return bool(np.array_equal(lu.perm_r, lu.perm_c) and np.all(lu.U.diagonal() > 0))

    def kkt(self, H, A, e, exact=False):
        return SparseKKT(kkt_matrix(H, A, e, self._layouts), "direct" if exact else self.method,
                         self.rtol, self.maxiter, self._orderings, self.band_max)
