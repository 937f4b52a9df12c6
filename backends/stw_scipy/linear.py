"""Sparse solvers for the symmetric indefinite Lagrange–Newton (KKT) system.

    K = [[H, Aᵀ], [A, -εI]]        K [d; λ] = [-g; -c]

``cg`` is the paper's route: conjugate gradients on the least-squares (normal equation) form
KᵀK x = Kᵀb, which is symmetric positive definite even though K is indefinite. ``minres`` works on
K directly (K is symmetric). ``direct`` factorizes K once (SuperLU) and can re-solve cheaply, which
the line search's second-order correction uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

SOLVERS = ("direct", "minres", "cg")
FALLBACK_RESIDUAL = 1e-6   # relative KKT residual above which an iterative solve is not trusted


@dataclass
class LinearSolve:
    """A solved KKT system that can solve again with another right-hand side."""

    x: np.ndarray
    iterations: int
    resolve: callable
    fallback: bool = False     # the iterative solver failed and a factorization was used


def kkt_matrix(H: sps.csr_array, A: sps.csr_array, eps: float) -> sps.csc_array:
    m = A.shape[0]
    return sps.block_array([[H, A.T], [A, -eps * sps.eye_array(m)]], format="csc") if m else sps.csc_array(H)


def solve_kkt(K: sps.csc_array, rhs: np.ndarray, method: str, rtol: float, maxiter: int) -> LinearSolve:
    """Solve K x = rhs with ``method`` (one of SOLVERS)."""
    if method == "direct":
        lu = spla.splu(K, permc_spec="COLAMD")
        return LinearSolve(lu.solve(rhs), 1, lu.solve)

    def iterative(b: np.ndarray) -> tuple[np.ndarray, int]:
        count = [0]

        def tick(_):
            count[0] += 1

        if method == "minres":
            x, _ = spla.minres(K, b, rtol=rtol, maxiter=maxiter, callback=tick)
        else:  # cg on KᵀK (K symmetric, so KᵀK = K·K) with a Jacobi preconditioner
            normal = spla.LinearOperator(K.shape, matvec=lambda v: K @ (K @ v), dtype=float)
            diag = np.asarray((K.multiply(K)).sum(axis=0)).ravel()
            precond = spla.LinearOperator(K.shape, matvec=lambda v: v / np.where(diag > 0, diag, 1.0),
                                          dtype=float)
            x, _ = spla.cg(normal, K @ b, rtol=rtol, maxiter=maxiter, M=precond, callback=tick)
        return x, count[0]

    with np.errstate(all="ignore"):   # a diverging Krylov run is detected below, not warned about
        x, its = iterative(rhs)
    if _acceptable(K, x, rhs):
        def resolve(b):
            with np.errstate(all="ignore"):
                y = iterative(b)[0]
            return y if _acceptable(K, y, b) else spla.splu(K, permc_spec="COLAMD").solve(b)
        return LinearSolve(x, its, resolve, fallback=False)
    # Barrier-scaled interior-point systems can defeat unpreconditioned Krylov methods: rather
    # than take a wrong step, factorize (and say so in the iteration report).
    direct = solve_kkt(K, rhs, "direct", rtol, maxiter)
    return LinearSolve(direct.x, its, direct.resolve, fallback=True)


def _acceptable(K, x, b) -> bool:
    if not np.all(np.isfinite(x)):
        return False
    return float(np.linalg.norm(K @ x - b)) <= FALLBACK_RESIDUAL * max(1.0, float(np.linalg.norm(b)))
