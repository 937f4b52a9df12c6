"""The scipy backend's dense numpy algebra (small windows) against plain numpy and against the
sparse algebra it stands in for."""

import numpy as np
import pytest
import scipy.sparse as sps

import catalogue

catalogue.backend_package("stw_scipy")

from stw_scipy.dense import DENSE_MAX, NumpyDenseAlgebra, window_rows  # noqa: E402
from stw_scipy.linear import SparseAlgebra  # noqa: E402

from stw_tui.sos.sqp.algebra import SingularSystem  # noqa: E402


def _kkt_parts(rng, n=12, m=5):
    B = rng.standard_normal((n, n))
    H = B @ B.T + n * np.eye(n)
    A = rng.standard_normal((m, n))
    return H, A


@pytest.mark.parametrize("e", [0.0, 1e-8, "rows"])
def test_dense_kkt_solves_the_assembled_system(e):
    """K = [[H, Aᵀ], [A, -diag(e)]] solved by LAPACK's LU matches numpy's solve of the same K,
    for e zero, a scalar and one entry per row; and matches the sparse algebra's solve."""
    rng = np.random.default_rng(3)
    H, A = _kkt_parts(rng)
    m = A.shape[0]
    e = rng.uniform(1e-6, 1e-3, m) if e == "rows" else e
    K = np.block([[H, A.T], [A, -np.diag(np.broadcast_to(e, (m,)))]])
    rhs = rng.standard_normal(K.shape[0])
    la = NumpyDenseAlgebra()
    x = la.kkt(la.matrix(sps.csr_array(H)), la.matrix(sps.csr_array(A)), e).solve(rhs)
    assert np.allclose(x, np.linalg.solve(K, rhs), rtol=1e-10, atol=1e-12)
    sparse = SparseAlgebra()
    y = sparse.kkt(sps.csr_array(H), sps.csr_array(A), e).solve(rhs)
    assert np.abs(x - y).max() <= 1e-10 * np.abs(y).max()


def test_dense_kkt_without_rows_is_h_alone_and_singular_systems_raise():
    rng = np.random.default_rng(4)
    H, _ = _kkt_parts(rng, n=6)
    la = NumpyDenseAlgebra()
    rhs = rng.standard_normal(6)
    assert np.allclose(la.kkt(H, np.zeros((0, 6)), 0.0).solve(rhs), np.linalg.solve(H, rhs))
    singular = np.zeros((3, 3))
    singular[0, 0] = 1.0
    with pytest.raises(SingularSystem):
        la.kkt(singular, np.zeros((0, 3)), 0.0)
    # two equal constraint rows and no regularization: K is exactly singular
    A = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    with pytest.raises(SingularSystem):
        la.kkt(np.eye(3), A, 0.0)


def test_dense_matrix_operations_match_the_sparse_ones():
    rng = np.random.default_rng(5)
    a = sps.random_array((9, 7), density=0.4, random_state=rng, format="csr")
    b = sps.random_array((9, 7), density=0.4, random_state=rng, format="csr")
    w = rng.uniform(0.1, 2.0, 9)
    x = rng.standard_normal(7)
    dense, sparse = NumpyDenseAlgebra(), SparseAlgebra()
    A, B = dense.matrix(a), dense.matrix(b)
    assert np.allclose(dense.gram(A, w), sparse.gram(a, w).toarray())
    assert np.allclose(dense.row_squares(A), sparse.row_squares(a), rtol=1e-14, atol=0)
    assert np.allclose(dense.add(A, B), sparse.add(a, b).toarray())
    assert np.allclose(dense.matvec(A, x), sparse.matvec(a, x))
    assert np.allclose(dense.rmatvec(A, w), sparse.rmatvec(a, w))
    rows = np.array([4, 0, 7])
    assert np.array_equal(dense.rows(A, rows), sparse.rows(a, rows).toarray())
    assert np.array_equal(dense.stack_rows([A, B]), sparse.stack_rows([a, b]).toarray())
    assert np.array_equal(dense.diagonal_matrix(w), np.diag(w))
    assert dense.max_step(np.ones(3), np.array([-0.5, 1.0, -4.0])) == 0.25
    assert dense.max_step(np.ones(3), np.ones(3), cap=0.7) == 0.7


def test_positive_definite_as_the_eigenvalues_say():
    rng = np.random.default_rng(6)
    B = rng.standard_normal((8, 8))
    M = B @ B.T
    lowest = float(np.linalg.eigvalsh(M).min())
    la = NumpyDenseAlgebra()
    assert la.positive_definite(M + 1e-3 * np.eye(8))
    assert not la.positive_definite(M - 2.0 * lowest * np.eye(8) - 1e-3 * np.eye(8))
    bad = M + np.eye(8)
    bad[3, 3] = np.nan
    assert not la.positive_definite(bad)
    before = M.copy()
    la.positive_definite(M)
    assert np.array_equal(M, before)   # the test leaves its matrix as it was


def test_the_scipy_backend_goes_dense_on_small_windows_only():
    """`factor=auto` picks the dense algebra up to DENSE_MAX rows (free control points plus
    equality and inequality rows), the sparse one above it and for the iterative solvers."""
    from stw_scipy.sqp import ScipyBackend

    from stw_tui.session.session import Session
    from stw_tui.sos.backend import create_backend
    from stw_tui.sos.window import WindowProblem

    def algebra(spans, options=""):
        s = Session()
        s.run_text(f"time 0 1 knots={spans}\ndof x\nconstraint c: x = 1 @ 1\nobjective e: x''")
        problem = WindowProblem(s.scene)
        backend = create_backend(ScipyBackend, dict(o.split("=") for o in options.split()))
        return window_rows(problem), type(backend.algebra(problem)).__name__

    assert algebra(20) == (24, "NumpyDenseAlgebra")
    rows, kind = algebra(DENSE_MAX)       # DENSE_MAX spans: DENSE_MAX + 3 control points
    assert rows > DENSE_MAX and kind == "SparseAlgebra"
    assert algebra(20, "solver=minres")[1] == "SparseAlgebra"
    assert algebra(20, "factor=sparse")[1] == "SparseAlgebra"
    assert algebra(DENSE_MAX, "factor=dense")[1] == "NumpyDenseAlgebra"


def test_a_jacobian_object_is_made_dense_once_and_a_new_one_anew():
    """The dense algebra keeps the dense copy of the last Jacobian object of each kind (the one
    object of an all-affine kind, shared by every evaluation), read-only; a new object (a
    nonlinear kind's next evaluation) is made dense anew, never answered by the kept copy."""
    from types import SimpleNamespace

    rng = np.random.default_rng(5)
    first, second = (sps.csr_array(rng.standard_normal((4, 6))) for _ in range(2))
    empty = sps.csr_array((0, 6))
    la = NumpyDenseAlgebra()
    one = la.jacobian(SimpleNamespace(J_eq=first, J_ge=empty), "eq")
    again = la.jacobian(SimpleNamespace(J_eq=first, J_ge=empty), "eq")
    assert again is one and np.array_equal(one, first.toarray()) and not one.flags.writeable
    other = la.jacobian(SimpleNamespace(J_eq=second, J_ge=empty), "eq")
    assert np.array_equal(other, second.toarray()) and not np.array_equal(other, one)
    assert la.jacobian(SimpleNamespace(J_eq=second, J_ge=empty), "ge").shape == (0, 6)
    # every row in order is the matrix itself; any other choice of rows is a copy of them
    assert la.rows(other, np.arange(4)) is other
    assert np.array_equal(la.rows(other, np.array([2, 0])), second.toarray()[[2, 0]])
    # the rows' sums of squares of a kept (read-only) matrix are kept too; a writable one's are
    # worked out anew
    squares = (second.toarray() ** 2).sum(axis=1)
    assert np.allclose(la.row_squares(other), squares, rtol=1e-14, atol=0)
    assert la.row_squares(other) is la.row_squares(other)
    writable = second.toarray()
    assert np.allclose(la.row_squares(writable), squares, rtol=1e-14, atol=0)
    writable *= 2.0
    assert np.allclose(la.row_squares(writable), 4.0 * squares, rtol=1e-14, atol=0)
