"""Dense torch linear algebra for the shared SQP: KKT systems factorized by torch.linalg (LU with
pivoting) on the device that holds the problem, where a dense factorization of a window's tens to
thousands of rows beats moving sparse matrices to the host (on a CPU, ``linear=scipy`` scales better)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
import torch

from stw_tui.sos.sqp.algebra import DenseMatrices, KKTSystem, LinearAlgebra, SingularSystem


def kkt_matrix(H: torch.Tensor, A: torch.Tensor, e) -> torch.Tensor:
    """The dense K = [[H, Aᵀ], [A, -diag(e)]] (H itself without rows)."""
    m = A.shape[0]
    if not m:
        return H
    E = torch.diag(torch.as_tensor(e, dtype=H.dtype, device=H.device).expand(m))
    return torch.cat([torch.cat([H, A.T], 1), torch.cat([A, -E], 1)], 0)


class DenseKKT(KKTSystem):
    """An LU factorization of K = [[H, Aᵀ], [A, -diag(e)]] that solves for any right-hand side,
    by torch on the device (stw_scipy.dense's, the same layout, is LAPACK's on numpy arrays)."""

    def __init__(self, H: torch.Tensor, A: torch.Tensor, e):
        K = kkt_matrix(H, A, e)
        self.LU, self.pivots, info = torch.linalg.lu_factor_ex(K)
        if int(info) > 0:
            raise SingularSystem("KKT matrix is exactly singular")
        self.iterations, self.fallbacks = 1, 0

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        return torch.linalg.lu_solve(self.LU, self.pivots, rhs.unsqueeze(1)).squeeze(1)


class DenseAlgebra(DenseMatrices, LinearAlgebra):
    """float64 tensors and dense matrices on one device."""

    def __init__(self, device: torch.device):
        self.device = device
        self._dev = dict(dtype=torch.float64, device=device)

    def vector(self, values):
        return torch.as_tensor(np.asarray(values, float), **self._dev).clone()

    def numpy(self, v):
        return v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else np.asarray(v, float)

    def full(self, n, value):
        return torch.full((n,), float(value), **self._dev)

    def concat(self, parts):
        return torch.cat(list(parts))

    def maximum(self, v, floor):
        return torch.clamp(v, min=floor)

    def max_abs(self, v):
        return float(v.abs().max()) if v.numel() else 0.0

    def matrix(self, m):
        if isinstance(m, torch.Tensor):
            return m
        return torch.as_tensor(m.toarray() if sps.issparse(m) else np.asarray(m), **self._dev)

    def diagonal_matrix(self, v):
        return torch.diag(torch.as_tensor(np.asarray(v, float), **self._dev))

    def rows(self, m, index):
        return m[torch.as_tensor(index, dtype=torch.long, device=self.device)]

    def stack_rows(self, parts):
        return torch.cat(list(parts), 0)

    def max_abs_diagonal(self, m):
        return float(m.diagonal().abs().max()) if m.numel() else 0.0

    def row_squares(self, a):
        return (a * a).sum(dim=1).cpu().numpy()

    def positive_definite(self, m):
        return int(torch.linalg.cholesky_ex(m).info) == 0

    def kkt(self, H, A, e, exact=False):
        return DenseKKT(H, A, e)

    def jacobian(self, ev, kind):
        if hasattr(ev, "dense_jacobian"):   # a torch evaluation: straight from its device values
            return ev.dense_jacobian(kind)
        return super().jacobian(ev, kind)
