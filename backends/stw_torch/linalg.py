"""The SQP subproblem on torch: dense KKT systems factorized by torch.linalg (LU with pivoting).

The same QP and the same interior-point method as ``stw_scipy.qp`` (Mehrotra predictor–corrector
on [[H + A_iᵀ(Z/W)A_i, A_eᵀ], [A_e, -εI]]), written on tensors so that it runs on the device that
holds the problem. Window problems are small (tens to a few thousand free control points), where a
dense factorization on a GPU beats moving sparse matrices to the host; on a CPU the sparse
``linear=scipy`` path scales better.
"""

from __future__ import annotations

import torch

from stw_scipy.qp import KKT_EPS, STEP_TO_BOUNDARY, QPResult


class DenseKKT:
    """An LU factorization of K = [[H, Aᵀ], [A, -εI]] that solves for any right-hand side."""

    def __init__(self, H: torch.Tensor, A: torch.Tensor, eps: float = KKT_EPS):
        m = A.shape[0]
        if m:
            K = torch.cat([torch.cat([H, A.T], 1),
                           torch.cat([A, -eps * torch.eye(m, dtype=H.dtype, device=H.device)], 1)], 0)
        else:
            K = H
        self.LU, self.pivots, info = torch.linalg.lu_factor_ex(K)
        if int(info) > 0:
            raise RuntimeError("KKT matrix is exactly singular")

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        return torch.linalg.lu_solve(self.LU, self.pivots, rhs.unsqueeze(1)).squeeze(1)


def solve_qp(H, g, Ae, ce, Ai, ci, y0=None, tol: float = 1e-11, max_ipm: int = 100) -> QPResult:
    """min ½dᵀHd + gᵀd s.t. Ae d + ce = 0, Ai d + ci >= 0 (all tensors, one device).

    As in ``stw_scipy.qp.solve_qp``, equality rows are stabilized around the previous multipliers
    ``y0``: A_e d + c_e = ε (y - y0).
    """
    n, me, mi = H.shape[0], Ae.shape[0], Ai.shape[0]
    y0 = g.new_zeros(me) if y0 is None else y0
    if mi == 0:
        x = DenseKKT(H, Ae).solve(torch.cat([-g, -ce - KKT_EPS * y0]))
        return QPResult(x[:n], x[n:], g.new_zeros(0), 1, 0)

    d, y = g.new_zeros(n), y0.clone()
    w = torch.clamp(ci, min=1.0)
    z = torch.ones_like(ci)
    scale_d = 1.0 + float(g.abs().max()) if n else 1.0
    scale_c = 1.0 + max(float(ce.abs().max()) if me else 0.0, float(ci.abs().max()))
    AeT, AiT = Ae.T, Ai.T
    linear_its = 0
    for k in range(1, max_ipm + 1):
        r_d = H @ d + g + (AeT @ y if me else 0.0) - AiT @ z
        r_e = Ae @ d + ce - KKT_EPS * (y - y0) if me else g.new_zeros(0)
        r_i = Ai @ d + ci - w
        mu = float(w @ z) / mi
        if (float(r_d.abs().max()) <= tol * scale_d and float(r_i.abs().max()) <= tol * scale_c
                and (float(r_e.abs().max()) if me else 0.0) <= tol * scale_c and mu <= tol * scale_d):
            break
        D = z / w
        kkt = DenseKKT(H + AiT @ (D[:, None] * Ai), Ae)
        linear_its += 1

        def newton(rc):
            x = kkt.solve(torch.cat([-r_d - AiT @ ((rc + z * r_i) / w), -r_e]))
            dd, dy = x[:n], x[n:]
            dw = Ai @ dd + r_i
            dz = -(rc + z * dw) / w
            return dd, dy, dw, dz

        dd, dy, dw, dz = newton(w * z)
        ap, ad = _max_step(w, dw), _max_step(z, dz)
        mu_aff = float((w + ap * dw) @ (z + ad * dz)) / mi
        sigma = (mu_aff / mu) ** 3 if mu > 0 else 0.0
        dd, dy, dw, dz = newton(w * z + dw * dz - sigma * mu)
        ap = min(1.0, STEP_TO_BOUNDARY * _max_step(w, dw, 1e30))
        ad = min(1.0, STEP_TO_BOUNDARY * _max_step(z, dz, 1e30))
        d = d + ap * dd
        w = w + ap * dw
        y = y + ad * dy
        z = z + ad * dz
    return QPResult(d, y, z, linear_its, k)


def _max_step(v: torch.Tensor, dv: torch.Tensor, cap: float = 1.0) -> float:
    """Largest α <= cap keeping v + α dv >= 0."""
    neg = dv < 0
    if not bool(neg.any()):
        return cap
    return float(min(cap, float((-v[neg] / dv[neg]).min())))
