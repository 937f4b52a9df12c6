"""Dense numpy linear algebra for the shared SQP on small windows: KKT systems factorized by
LAPACK's LU with partial pivoting (``dgetrf``), positive-definiteness tests by its Cholesky.

On a window of a few hundred rows or fewer, a dense factorization costs microseconds and every
sparse operation around it (sums, row selections, the KKT's assembly, SuperLU's setup) costs tens
of microseconds of fixed overhead; there, the sparse path's bookkeeping is most of an iteration.
The evaluation's sparse Jacobians and Hessians are made dense once, as they enter the SQP.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
from scipy.linalg import lapack

from stw_tui.sos.sqp.algebra import DenseMatrices, KKTSystem, SingularSystem
from stw_tui.sym.kinds import TermKind
from stw_scipy.vectors import NumpyVectors

# Windows up to this many rows (free control points + equality rows + inequality rows) run dense.
# Measured per solve against the sparse path (banded LU or SuperLU): point_mass_2d's 111 rows
# 9.2 -> 6.5 ms, acrobat's window solves (163, 165 rows) 10.4 -> 8.0 and 8.3 -> 6.4 ms, the
# arm's second window (222 rows) 19.0 -> 17.3 ms; the pendulum (27 rows) 8% of its whole `iterate`.
DENSE_MAX = 250


def window_rows(problem) -> int:
    """The size :data:`DENSE_MAX` is compared with: the window's free control points and its
    equality and inequality rows."""
    counts = problem.row_counts
    return problem.n_free + counts.get(TermKind.EQ, 0) + counts.get(TermKind.GE, 0)


class DenseKKT(KKTSystem):
    """An LU factorization of K = [[H, Aᵀ], [A, -diag(e)]] that solves for any right-hand side.

    stw_torch.linalg has its own: the same block layout, assembled and factorized there by
    torch on the device that holds the problem; here in LAPACK's Fortran order, K's (2,2)
    diagonal written through a strided view, and dgetrf without a copy (numpy only)."""

    def __init__(self, H: np.ndarray, A: np.ndarray, e):
        n, m = H.shape[0], A.shape[0]
        size = n + m
        K = np.zeros((size, size), order="F")   # LAPACK's order: dgetrf would copy a C array
        K[:n, :n] = H
        if m:
            K[:n, n:] = A.T
            K[n:, :n] = A
            # the (2,2) diagonal through a strided view of the storage (entry (i, i) is i(size+1)),
            # not a fancy index: a scalar or one entry per row
            K.ravel(order="F")[n * (size + 1)::size + 1] = -np.asarray(e, dtype=float)
        self.lu, self.pivots, info = lapack.dgetrf(K, overwrite_a=1)
        if info > 0:   # U[info-1, info-1] is exactly zero
            raise SingularSystem("KKT matrix is exactly singular")
        self.iterations, self.fallbacks = 1, 0

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        x, _info = lapack.dgetrs(self.lu, self.pivots, rhs)
        return x


class NumpyDenseAlgebra(DenseMatrices, NumpyVectors):
    """numpy vectors and dense 2-D arrays; LAPACK's LU and Cholesky. One per solve."""

    def __init__(self):
        # kind -> (the evaluation's sparse Jacobian, dense); "row_squares" -> (a read-only matrix,
        # its row_squares)
        self._kept: dict[str, tuple] = {}

    def matrix(self, m):
        return m.toarray() if sps.issparse(m) else np.asarray(m, dtype=float)

    def jacobian(self, ev, kind):
        # A kind whose rows are all affine (or absent) has one Jacobian object for every
        # evaluation of the window (WindowProblem.evaluate): made dense once a solve, read-only.
        sparse = ev.J_eq if kind == "eq" else ev.J_ge
        kept = self._kept.get(kind)
        if kept is None or kept[0] is not sparse:
            dense = self.matrix(sparse)
            dense.flags.writeable = False
            kept = self._kept[kind] = (sparse, dense)
        return kept[1]

    def diagonal_matrix(self, v):
        return np.diag(np.asarray(v, dtype=float))

    def rows(self, m, index):
        if index.size == m.shape[0] and np.array_equal(index, np.arange(index.size)):
            return m   # every row, in order: m[index] would copy m as it is
        return m[index]

    def stack_rows(self, parts):
        return np.vstack(parts)

    def max_abs_diagonal(self, m):
        return float(np.abs(m.diagonal()).max(initial=0.0))

    def row_squares(self, a):
        # the curvature test asks it of the same kept (read-only) Jacobian at every step
        kept = self._kept.get("row_squares")
        if kept is not None and kept[0] is a:
            return kept[1]
        squares = np.einsum("ij,ij->i", a, a)
        if not a.flags.writeable:
            self._kept["row_squares"] = (a, squares)
        return squares

    def positive_definite(self, m):
        # LAPACK may carry a NaN through instead of stopping: a NaN entry reaches a pivot.
        factor, info = lapack.dpotrf(m, lower=1, overwrite_a=0, clean=0)
        return info == 0 and bool(np.isfinite(factor.diagonal()).all())

    def kkt(self, H, A, e, exact=False):
        return DenseKKT(H, A, e)
