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

from stw_tui.sqp.algebra import KKTSystem, LinearAlgebra, SingularSystem

SOLVERS = ("direct", "minres", "cg")
FALLBACK_RESIDUAL = 1e-6   # relative KKT residual above which an iterative solve is not trusted


def kkt_matrix(H, A, e) -> sps.csc_array:
    m = A.shape[0]
    if not m:
        return sps.csc_array(H)
    E = sps.diags_array(np.broadcast_to(np.asarray(e, float), (m,)))
    return sps.block_array([[H, A.T], [A, -E]], format="csc")


class SparseKKT(KKTSystem):
    """K solved by SuperLU (``direct``) or by MINRES / CG with a factorization as fallback."""

    def __init__(self, K: sps.csc_array, method: str, rtol: float, maxiter: int):
        self.K, self.method, self.rtol, self.maxiter = K, method, rtol, maxiter
        self.iterations = self.fallbacks = 0
        self._lu = None
        if method == "direct":
            self._factorize()

    def _factorize(self):
        if self._lu is None:
            try:
                self._lu = spla.splu(self.K, permc_spec="COLAMD")
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


class SparseAlgebra(LinearAlgebra):
    """numpy vectors, scipy sparse (CSR) matrices, KKT systems by SuperLU, MINRES or CG."""

    def __init__(self, method: str = "direct", rtol: float = 1e-12, maxiter: int = 1000):
        self.method, self.rtol, self.maxiter = method, rtol, maxiter

    def vector(self, values):
        return np.array(values, dtype=float)

    def numpy(self, v):
        return np.asarray(v, dtype=float)

    def full(self, n, value):
        return np.full(n, float(value))

    def concat(self, parts):
        return np.concatenate(parts)

    def maximum(self, v, floor):
        return np.maximum(v, floor)

    def max_abs(self, v):
        return float(np.abs(v).max(initial=0.0))

    def matrix(self, m):
        return m if isinstance(m, sps.csr_array) else sps.csr_array(m)

    def diagonal_matrix(self, v):
        return sps.diags_array(np.asarray(v, float), format="csr")

    def rows(self, m, index):
        return m[index]

    def stack_rows(self, parts):
        return sps.vstack(parts, format="csr")

    def matvec(self, m, x):
        return m @ x

    def rmatvec(self, m, x):
        return m.T @ x

    def add(self, a, b):
        return sps.csr_array(a + b)

    def gram(self, a, w):
        return sps.csr_array(a.T @ (sps.diags_array(w) @ a))

    def max_abs_diagonal(self, m):
        return float(np.abs(m.diagonal()).max(initial=0.0))

    def kkt(self, H, A, e, exact=False):
        return SparseKKT(kkt_matrix(H, A, e), "direct" if exact else self.method, self.rtol, self.maxiter)
