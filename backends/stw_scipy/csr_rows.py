"""Rows of CSR matrices taken and stacked without scipy's general indexing machinery.

Each SQP step takes the binding inequality rows out of the Jacobian and stacks them under the
equality rows (the working-set QP, the curvature test, the second-order correction). ``m[index]``
and ``sps.vstack`` validate and convert their arguments in Python at several times the cost of
the copy itself on these few-hundred-row matrices. These copy the same stored entries in the
same order (rows as stored, blocks one after the other), so every matrix built from them, and
every factorization, is what it was.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from stw_tui.sos.compressed import csr


def select_rows(m: sps.csr_array, index: np.ndarray) -> sps.csr_array:
    """``m[index]`` for a CSR ``m`` and an array of row numbers ``index`` (>= 0)."""
    index = np.asarray(index, dtype=np.intp)
    starts = m.indptr[index]
    counts = m.indptr[index + 1] - starts
    indptr = np.zeros(index.size + 1, dtype=m.indptr.dtype)
    np.cumsum(counts, out=indptr[1:])
    take = np.repeat(starts - indptr[:-1], counts) + np.arange(indptr[-1])
    return csr(m.data[take], m.indices[take], indptr, (index.size, m.shape[1]))


def stack_rows(parts: list[sps.csr_array]) -> sps.csr_array:
    """``sps.vstack(parts, format="csr")`` for CSR parts of one width."""
    nnz = [int(p.indptr[-1]) for p in parts]
    offsets = np.cumsum([0] + nnz[:-1])
    indptr = np.concatenate([parts[0].indptr[:1].astype(np.int64)]
                            + [p.indptr[1:].astype(np.int64) + o for p, o in zip(parts, offsets)])
    if indptr[-1] < np.iinfo(np.int32).max:   # the index dtype the constructor would choose
        indptr = indptr.astype(np.int32)
    data = np.concatenate([p.data[:k] for p, k in zip(parts, nnz)])
    indices = np.concatenate([p.indices[:k] for p, k in zip(parts, nnz)])
    return csr(data, indices, indptr, (sum(p.shape[0] for p in parts), parts[0].shape[1]))
