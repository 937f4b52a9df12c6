"""The SciPy backend's shortcuts are the operations they replace, bit for bit (any difference would
move every later iterate): direct sparse kernels (stw_tui/sos/sparse_matvec.py), arrays built
without scipy's checks, their sum and transpose (stw_tui/sos/compressed.py), CSR row selection
and stacking (backends/stw_scipy/csr_rows.py), and the algebra's ratio test."""

import numpy as np
import pytest
import scipy.sparse as sps

from stw_scipy.csr_rows import select_rows, stack_rows
from stw_scipy.linear import SparseAlgebra
from stw_tui.sos import compressed
from stw_tui.sos.sparse_matvec import matvec
from stw_tui.sos.sqp.algebra import LinearAlgebra


@pytest.mark.parametrize("fmt", ["csr", "csc"])
def test_matvec_is_scipys_product_bit_for_bit(fmt):
    rng = np.random.default_rng(3)
    for _ in range(30):
        m, n = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        A = sps.random_array((m, n), density=rng.random(), rng=rng, format=fmt)
        A.data[:] = rng.standard_normal(A.nnz) * 10.0 ** rng.integers(-8, 8, A.nnz)
        x = rng.standard_normal(n)
        assert np.array_equal(matvec(A, x), A @ x)
        y = rng.standard_normal(m)
        assert np.array_equal(matvec(A.T, y), A.T @ y)
        M = sps.csr_matrix(A) if fmt == "csr" else sps.csc_matrix(A)   # the matrix classes too
        assert np.array_equal(matvec(M, x), M @ x)


@pytest.mark.parametrize("parts", [2, 3, 4])
def test_a_large_product_split_over_cores_is_scipys_bit_for_bit(monkeypatch, parts):
    from stw_tui.sos import sparse_matvec

    monkeypatch.setattr(sparse_matvec, "_PARTS", parts)
    monkeypatch.setattr(sparse_matvec, "_POOL", None)
    monkeypatch.setattr(sparse_matvec, "PARALLEL_NNZ", 200_000)   # split a product of this size
    rng = np.random.default_rng(9)
    counts = rng.integers(0, 60, 9000)
    counts[4000:4300] = 0                                    # empty rows, and a range of them
    indptr = np.concatenate([[0], np.cumsum(counts)])
    indices = np.concatenate([np.sort(rng.choice(5000, c, replace=False)) for c in counts])
    data = rng.standard_normal(indptr[-1]) * 10.0 ** rng.integers(-8, 8, indptr[-1])
    A = sps.csr_array((data, indices, indptr), shape=(counts.size, 5000))
    assert A.nnz >= sparse_matvec.PARALLEL_NNZ
    x = rng.standard_normal(5000)
    assert np.array_equal(matvec(A, x), A @ x)
    small = A[:10]
    assert np.array_equal(matvec(small, x), small @ x)        # below the threshold: one call
    # a process forked with the pool in place (a survey's worker) makes its own threads
    monkeypatch.setattr(sparse_matvec, "_POOL", (-1, sparse_matvec._pool()))
    assert sparse_matvec._pool() is not None and sparse_matvec._POOL[0] != -1
    assert np.array_equal(matvec(A, x), A @ x)


def test_matvec_takes_the_ordinary_route_for_what_the_kernel_does_not_take():
    A = sps.csr_array(np.array([[1.0, 2.0], [0.0, 3.0]]))
    assert np.array_equal(matvec(A, np.array([1, 2])), [5.0, 6.0])            # an int vector
    assert np.array_equal(matvec(sps.coo_array(A), np.ones(2)), [3.0, 3.0])   # not CSR/CSC
    single = sps.csr_array(np.array([[1.0, 2.0], [0.0, 3.0]], np.float32))
    assert np.array_equal(matvec(single, np.ones(2)), single @ np.ones(2))   # float32 values
    with pytest.raises(ValueError):
        matvec(A, np.ones(3))                                                 # scipy's shape error


def test_the_ratio_test_is_the_generic_one_bit_for_bit():
    la, rng = SparseAlgebra(), np.random.default_rng(5)
    generic = LinearAlgebra.max_step
    cases = [(np.zeros(0), np.zeros(0)), (np.ones(3), np.ones(3)), (np.ones(2), np.array([-1e-300, 1.0]))]
    for _ in range(200):
        n = int(rng.integers(1, 50))
        cases.append((rng.random(n) * 10.0 ** rng.integers(-10, 5), rng.standard_normal(n)
                      * 10.0 ** rng.integers(-10, 10)))
    for v, dv in cases:
        for cap in (1.0, 1e30):
            assert la.max_step(v, dv, cap) == generic(la, v, dv, cap)


def test_rows_taken_and_stacked_are_scipys_bit_for_bit():
    rng = np.random.default_rng(7)
    for _ in range(40):
        m, n = int(rng.integers(0, 30)), int(rng.integers(1, 30))
        A = sps.csr_array(sps.random_array((m, n), density=rng.random(), rng=rng, format="csr")
                          + sps.random_array((m, n), density=0.2, rng=rng, format="csr"))
        A.data[rng.random(A.nnz) < 0.1] = 0.0     # stored zeros stay
        if A.nnz > 1 and A.indptr[1] > 1:         # a row stored out of column order stays so
            A.indices[:2] = A.indices[1::-1].copy()
        index = np.sort(rng.choice(m, size=int(rng.integers(0, m + 1)), replace=False)) if m else np.zeros(0, int)
        B = sps.random_array((int(rng.integers(0, 5)), n), density=0.5, rng=rng, format="csr")
        for got, want in ((select_rows(A, index), A[index]),
                          (stack_rows([B, select_rows(A, index)]), sps.vstack([B, A[index]], format="csr"))):
            assert got.shape == want.shape
            assert np.array_equal(got.indptr, want.indptr) and np.array_equal(got.indices, want.indices)
            assert np.array_equal(got.data, want.data)


def _same(got, want):
    """Same class, shape, index dtype and stored parts (values bit for bit), and usable."""
    assert type(got) is type(want) and got.shape == want.shape
    assert got.indices.dtype == want.indices.dtype and got.indptr.dtype == want.indptr.dtype
    assert np.array_equal(got.indptr, want.indptr) and np.array_equal(got.indices, want.indices)
    assert np.array_equal(got.data, want.data)
    x = np.arange(1.0, got.shape[1] + 1)
    assert np.array_equal(got @ x, want @ x) and got.nnz == want.nnz


def _random_csr(rng, m, n):
    A = sps.random_array((m, n), density=rng.random(), rng=rng, format="csr")
    A.data[:] = rng.standard_normal(A.nnz) * 10.0 ** rng.integers(-8, 8, A.nnz)
    A.data[rng.random(A.nnz) < 0.1] = 0.0          # stored zeros stay
    return A


def test_arrays_built_without_checks_are_the_constructors():
    assert compressed._FAST   # this scipy's arrays can be built so (else every test here is moot)
    rng = np.random.default_rng(11)
    for _ in range(40):
        m, n = int(rng.integers(0, 30)), int(rng.integers(1, 30))
        A = _random_csr(rng, m, n)
        parts = (A.data, A.indices.astype(np.int32), A.indptr.astype(np.int32))
        _same(compressed.csr(*parts, (m, n)), sps.csr_array(parts, shape=(m, n)))
        _same(compressed.csc(*parts, (n, m)), sps.csc_array(parts, shape=(n, m)))
    # parts scipy would convert or prune take its constructor: the same array comes out
    d, i, p = np.array([1.0, 2.0, 9.0]), np.array([0, 1, 0]), np.array([0, 1, 2])   # int64, one extra
    _same(compressed.csr(d, i, p, (2, 2)), sps.csr_array((d, i, p), shape=(2, 2)))
    ints = np.array([1, 2])
    _same(compressed.csr(ints, i[:2].astype(np.int32), p.astype(np.int32), (2, 2)),
          sps.csr_array((ints, i[:2].astype(np.int32), p.astype(np.int32)), shape=(2, 2)))
    with pytest.raises(ValueError):                 # malformed parts: scipy's own error
        compressed.csr(d, i.astype(np.int32), np.array([0, 1], np.int32), (2, 2))


def test_sum_and_transpose_are_scipys_bit_for_bit():
    rng = np.random.default_rng(13)
    for _ in range(60):
        m, n = int(rng.integers(0, 30)), int(rng.integers(1, 30))
        A, B = _random_csr(rng, m, n), _random_csr(rng, m, n)
        B.data[: min(3, B.nnz)] *= 0.0
        if A.nnz and B.nnz:                          # entries that cancel: the sum leaves them out
            B = sps.csr_array(B + sps.csr_array((-A.data, A.indices, A.indptr), shape=A.shape))
        if A.nnz > 1 and A.indptr[1] > 1:            # a row stored out of column order
            A.indices[:2] = A.indices[1::-1].copy()
            A.has_sorted_indices = False
        _same(compressed.add(A, B), A + B)
        _same(compressed.transpose(A), A.T)
    C = sps.csc_array(A)                             # not CSR: scipy's own operations
    _same(compressed.add(C, sps.csc_array(B)), C + sps.csc_array(B))
    _same(compressed.transpose(C), C.T)
