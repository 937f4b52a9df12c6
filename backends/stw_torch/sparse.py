"""A fixed sparse matrix applied to torch tensors: torch's sparse CSR product on a CUDA device,
scipy's on the CPU, on the tensors' memory (a window's matrices: ~0.02 ms where torch's sparse
CSR product cost ~0.25). Both sum each row's products in order."""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sps
import torch

from stw_tui.sos.sparse_matvec import matvec


class SparseMatrix:
    """``m`` (scipy CSR) as an operator on (n,) or (n, B) float64 tensors on ``device``; ``m``
    is copied unless ``copy`` is False (its indices sorted in place then)."""

    def __init__(self, m, device: torch.device, copy: bool = True):
        m = sps.csr_array(m, copy=copy)   # copy=False: ``m`` is the caller's to give away
        m.sort_indices()
        self.shape = m.shape
        self.host = m if device.type == "cpu" else None
        self.tensor = None
        if self.host is None:
            as_t = lambda a: torch.as_tensor(a, device=device)  # noqa: E731
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "sparse CSR support is in beta state"
                self.tensor = torch.sparse_csr_tensor(
                    as_t(m.indptr.astype(np.int64)), as_t(m.indices.astype(np.int64)),
                    torch.as_tensor(m.data, dtype=torch.float64, device=device), size=m.shape,
                    check_invariants=False)

    def __matmul__(self, x: torch.Tensor) -> torch.Tensor:
        """``m @ x`` for x (n,) or (n, B)."""
        if self.host is not None:
            # scipy's kernel without its dispatch, bitwise (matvec takes ``@`` for what it can't)
            return torch.from_numpy(np.asarray(matvec(self.host, x.numpy())))
        if not self.shape[0]:
            return x.new_zeros((0, *x.shape[1:]))
        return self.tensor @ x

    def rows(self, X: torch.Tensor) -> torch.Tensor:
        """Each row of X (B, n) times the matrix: (B, m)."""
        if X.shape[0] == 1:
            return (self @ X[0]).unsqueeze(0)
        return (self @ X.T.contiguous()).T
