"""The SQP subproblem: a sparse convex QP with equality and inequality rows.

    min ½dᵀHd + gᵀd   s.t.   A_e d + c_e = 0,   A_i d + c_i >= 0

With no inequality rows this is one Lagrange–Newton (KKT) solve, the paper's step. With them, a
primal–dual interior-point method (Mehrotra predictor–corrector) decides which instances bind:
each of its iterations solves a KKT system of the same shape, [[H + A_iᵀ(Z/W)A_i, A_eᵀ], [A_e, 0]],
with the chosen linear solver. It is robust where a per-instance active-set rule cycles — dense
samples of a bound along a flat arc make the active rows linearly dependent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sps

from .linear import kkt_matrix, solve_kkt

STEP_TO_BOUNDARY = 0.995   # fraction of the way to w = 0 or z = 0 an IPM step may go
KKT_EPS = 1e-10            # small negative (2,2) block: redundant (densely sampled) constraint rows get bounded multipliers


@dataclass
class QPResult:
    d: np.ndarray
    y: np.ndarray           # equality multipliers (L = R + yᵀc_e)
    z: np.ndarray           # inequality multipliers, >= 0 (L = R - zᵀc_i)
    linear_iterations: int
    ipm_iterations: int
    fallbacks: int = 0      # iterative solves that had to be replaced by a factorization


def solve_qp(H, g, Ae, ce, Ai, ci, method: str, rtol: float, maxiter: int,
             y0: np.ndarray | None = None, tol: float = 1e-11, max_ipm: int = 100) -> QPResult:
    """Solve the QP; ``method`` names the linear solver (see linear.SOLVERS).

    The equality rows are stabilized around the previous multipliers ``y0`` (a proximal method
    of multipliers): A_e d + c_e = ε (y - y0). Redundant rows — a constraint sampled more densely
    than its spline can vary — then get bounded multipliers, and the constraints are still met
    exactly once the multipliers settle.
    """
    n, me, mi = H.shape[0], Ae.shape[0], Ai.shape[0]
    y0 = np.zeros(me) if y0 is None else y0
    if mi == 0:
        sol = solve_kkt(kkt_matrix(H, Ae, KKT_EPS), np.concatenate([-g, -ce - KKT_EPS * y0]), method,
                        rtol, maxiter)
        return QPResult(sol.x[:n], sol.x[n:], np.zeros(0), sol.iterations, 0, int(sol.fallback))

    # Barrier scaling makes these systems too ill-conditioned for unpreconditioned Krylov methods
    # (inexact steps drove w or z to zero and the iteration broke down): factorize them.
    method = "direct"
    d, y = np.zeros(n), y0.copy()
    w = np.maximum(ci, 1.0)
    z = np.ones(mi)
    AiT = Ai.T.tocsr()
    scale_d = 1.0 + np.abs(g).max(initial=0.0)
    scale_c = 1.0 + max(np.abs(ce).max(initial=0.0), np.abs(ci).max(initial=0.0))
    linear_its = fallbacks = 0
    for k in range(1, max_ipm + 1):
        r_d = H @ d + g + (Ae.T @ y if me else 0.0) - AiT @ z
        r_e = Ae @ d + ce - KKT_EPS * (y - y0) if me else np.zeros(0)
        r_i = Ai @ d + ci - w
        mu = float(w @ z) / mi
        if (np.abs(r_d).max() <= tol * scale_d and np.abs(r_i).max() <= tol * scale_c
                and np.abs(r_e).max(initial=0.0) <= tol * scale_c and mu <= tol * scale_d):
            break
        D = z / w
        K = kkt_matrix(H + AiT @ sps.diags_array(D) @ Ai, Ae, KKT_EPS)
        first = None

        def newton(rc):
            nonlocal first, linear_its, fallbacks
            rhs = np.concatenate([-r_d - AiT @ ((rc + z * r_i) / w), -r_e])
            if first is None:
                first = solve_kkt(K, rhs, method, rtol, maxiter)
                x = first.x
                linear_its += first.iterations
                fallbacks += int(first.fallback)
            else:
                x = first.resolve(rhs)
            dd, dy = x[:n], x[n:]
            dw = Ai @ dd + r_i
            dz = -(rc + z * dw) / w
            return dd, dy, dw, dz

        # Predictor (affine scaling), then Mehrotra's centring + second-order corrector.
        dd, dy, dw, dz = newton(w * z)
        ap, ad = _max_step(w, dw), _max_step(z, dz)
        mu_aff = float((w + ap * dw) @ (z + ad * dz)) / mi
        sigma = (mu_aff / mu) ** 3 if mu > 0 else 0.0
        dd, dy, dw, dz = newton(w * z + dw * dz - sigma * mu)
        ap = min(1.0, STEP_TO_BOUNDARY * _max_step(w, dw, 1e30))
        ad = min(1.0, STEP_TO_BOUNDARY * _max_step(z, dz, 1e30))
        d += ap * dd
        w += ap * dw
        y += ad * dy
        z += ad * dz
    return QPResult(d, y, z, linear_its, k, fallbacks)


def _max_step(v: np.ndarray, dv: np.ndarray, cap: float = 1.0) -> float:
    """Largest α <= cap keeping v + α dv >= 0."""
    neg = dv < 0
    if not neg.any():
        return cap
    return float(min(cap, (-v[neg] / dv[neg]).min()))
