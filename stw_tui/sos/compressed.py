"""Compressed sparse arrays made from parts already in scipy's own form, without its validation.

``sps.csr_array((data, indices, indptr), shape=...)`` chooses an index dtype, copies or converts
the three arrays and checks their format in Python: about 17 µs a matrix, where the arrays an SQP
step assembles (products of plans, KKT matrices, rows taken and stacked) are built a few dozen
times a step and are often smaller than that costs. :func:`csr` and :func:`csc` take parts that
are what scipy would keep anyway (float64 values, int32 indices and pointers, every length
consistent) and hand them over as they are: the array is the one the constructor would make,
entry for entry. Anything else takes the constructor, as does a scipy whose arrays this cannot
build (checked once, at import).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

_INT32, _FLOAT64 = np.dtype(np.int32), np.dtype(np.float64)
_MAXPRINT = getattr(sps.csr_array((1, 1)), "maxprint", None)   # what the constructor sets


def _unchecked(cls, data, indices, indptr, shape):
    m = cls.__new__(cls)
    m._shape, m.maxprint = shape, _MAXPRINT
    m.data, m.indices, m.indptr = data, indices, indptr
    return m


def _works() -> bool:
    """Whether this scipy's arrays come out of :func:`_unchecked` as its constructor makes them."""
    try:
        parts = np.array([1.0, 2.0]), np.array([1, 0], np.int32), np.array([0, 1, 2], np.int32)
        for cls in (sps.csr_array, sps.csc_array):
            fast, slow = _unchecked(cls, *parts, (2, 2)), cls(parts, shape=(2, 2))
            if not (vars(fast).keys() == vars(slow).keys() and fast.shape == slow.shape
                    and fast.nnz == slow.nnz and fast.format == slow.format
                    and np.array_equal(fast.toarray(), slow.toarray())
                    and np.array_equal(fast @ np.array([1.0, 3.0]), slow @ np.array([1.0, 3.0]))):
                return False
        return True
    except Exception:  # noqa: BLE001 - any failure means: use the constructor
        return False


_FAST = _works()


def _canonical_parts(data, indices, indptr, shape, major: int) -> bool:
    return (_FAST and data.__class__ is np.ndarray and indices.__class__ is np.ndarray
            and indptr.__class__ is np.ndarray and data.dtype == _FLOAT64 and indices.dtype == _INT32
            and indptr.dtype == _INT32 and data.ndim == 1 and indices.ndim == 1 and indptr.ndim == 1
            and indptr.size == major + 1 and indptr[0] == 0 and data.size == indices.size == indptr[-1]
            and max(shape) < 2**31 - 1)


def csr(data: np.ndarray, indices: np.ndarray, indptr: np.ndarray, shape: tuple[int, int]) -> sps.csr_array:
    """``sps.csr_array((data, indices, indptr), shape=shape)``, without its checks when the parts
    are already float64 / int32 / int32 of consistent lengths (the arrays are then shared)."""
    shape = (int(shape[0]), int(shape[1]))
    if _canonical_parts(data, indices, indptr, shape, shape[0]):
        return _unchecked(sps.csr_array, data, indices, indptr, shape)
    return sps.csr_array((data, indices, indptr), shape=shape)


def csc(data: np.ndarray, indices: np.ndarray, indptr: np.ndarray, shape: tuple[int, int]) -> sps.csc_array:
    """``sps.csc_array((data, indices, indptr), shape=shape)``, as :func:`csr` for columns."""
    shape = (int(shape[0]), int(shape[1]))
    if _canonical_parts(data, indices, indptr, shape, shape[1]):
        return _unchecked(sps.csc_array, data, indices, indptr, shape)
    return sps.csc_array((data, indices, indptr), shape=shape)


def transpose(m):
    """``m.T`` (sharing m's arrays, as scipy's does): a CSR array's transpose is the CSC array of
    the same parts."""
    if isinstance(m, sps.csr_array):
        return csc(m.data, m.indices, m.indptr, (m.shape[1], m.shape[0]))
    return m.T


try:   # the kernel scipy's own CSR sum calls (private, as sparse_matvec's; guarded anyway)
    from scipy.sparse._sparsetools import csr_plus_csr as _csr_plus_csr
except ImportError:   # pragma: no cover - a scipy that moved it: the public route
    _csr_plus_csr = None


def add(a, b):
    """``a + b`` for CSR arrays of one shape, bitwise as scipy sums them (its kernel, the same
    index dtype, exact zeros of the sum left out), without its conversions and checks."""
    if (_csr_plus_csr is None or not isinstance(a, sps.csr_array) or not isinstance(b, sps.csr_array)
            or a.shape != b.shape or not _canonical_parts(a.data, a.indices, a.indptr, a.shape, a.shape[0])
            or not _canonical_parts(b.data, b.indices, b.indptr, b.shape, b.shape[0])
            or a.data.size + b.data.size >= 2**31 - 1):
        return a + b
    most = a.data.size + b.data.size
    indptr, indices, data = np.empty(a.indptr.size, np.int32), np.empty(most, np.int32), np.empty(most)
    _csr_plus_csr(a.shape[0], a.shape[1], a.indptr, a.indices, a.data, b.indptr, b.indices, b.data,
                  indptr, indices, data)
    nnz = int(indptr[-1])
    return csr(data[:nnz], indices[:nnz], indptr, a.shape)


def structure(m) -> tuple:
    """A compressed array's sparsity structure (shape, pointers, indices; copies), to recognize
    the next array of the same structure by :func:`same_structure`."""
    return m.shape, m.indptr.copy(), m.indices[:m.indptr[-1]].copy()


def same_structure(m, key: tuple) -> bool:
    """Whether ``m`` has the structure ``key`` (:func:`structure`) of an earlier array."""
    shape, indptr, indices = key
    nnz = m.indptr[-1]
    return (m.shape == shape and nnz == indices.size and np.array_equal(m.indptr, indptr)
            and np.array_equal(m.indices[:nnz], indices))
