"""A window problem's slot matrix P, its free columns Pf and Pfᵀ, assembled directly in CSR
(window._stacked, window._columns), are the matrices scipy's own routes make: the same stored
entries in the same order, so nothing downstream can tell."""

import numpy as np
import pytest
import scipy.sparse as sps

from stw_tui.session.session import Session
from stw_tui.sos.window import BasisRows, WindowProblem, _columns, _stacked

SCENES = {
    "pendulum": "time 0 2 knots=20\nconst g = 9.81\ndof th\n"
                "constraint start: th = 0, th' = 0 @ 0\nconstraint goal: th = pi, th' = 0 @ 2\n"
                "objective effort: th'' + g*sin(th)\n",
    "window and bounds": "time 0 3 knots=12\ndof x, y lo=-1 hi=2\n"
                         "constraint c: x + y*y = 1 on [0.5, 1.5]\nconstraint s: x' = 0 @ 0\n"
                         "objective o: x'' + y''\nwindow w dofs=y [1, 2]\n",
    "conditional": "time 0 1 knots=8\ndof x, y\nconstraint c: y >= 0 on [0, 1] when x > 0.2\n"
                   "objective o: x'' + y''\n",
}


def same(a: sps.csr_array, b: sps.csr_array) -> bool:
    return (a.shape == b.shape and np.array_equal(a.indptr, b.indptr)
            and np.array_equal(a.indices, b.indices) and np.array_equal(a.data, b.data))


@pytest.mark.parametrize("text", SCENES.values(), ids=SCENES.keys())
def test_slot_matrices_are_scipys(text):
    session = Session()
    session.run_text(text)
    problem = WindowProblem(session.scene)
    assert same(problem.P, sps.csr_array(problem.P.tocoo()))      # canonical, as COO -> CSR makes it
    assert same(problem.Pf, problem.P[:, problem.free].tocsr())
    assert same(problem.PfT, problem.Pf.T.tocsr())
    assert problem.free.size < problem.n_total or "window" not in text   # the window's columns only


def test_stacked_rows_sort_each_rows_columns_and_fall_back_on_duplicates():
    rng = np.random.default_rng(3)
    blocks = []
    for n in (3, 1, 4):
        row = np.repeat(np.arange(n), 3)
        col = np.concatenate([rng.permutation(8)[:3] for _ in range(n)])   # columns out of order
        blocks.append(BasisRows(row, col, rng.standard_normal(3 * n), n))
    row = np.concatenate([b.row + s for b, s in zip(blocks, [0, 3, 4])])
    col, data = np.concatenate([b.col for b in blocks]), np.concatenate([b.data for b in blocks])
    want = sps.csr_array((data, (row, col)), shape=(8, 8))
    got = _stacked(blocks, 8)
    assert same(got, want) and got.indices.dtype == np.int32 and got.has_canonical_format
    twice = [BasisRows(np.array([0, 0]), np.array([2, 2]), np.array([1.0, 2.0]), 1)]
    assert same(_stacked(twice, 4), sps.csr_array((np.array([1.0, 2.0]), ([0, 0], [2, 2])), shape=(1, 4)))
    assert _stacked(twice, 4).toarray()[0, 2] == 3.0                  # summed, as scipy sums them


def test_columns_keep_each_rows_stored_order_for_any_column_order():
    rng = np.random.default_rng(5)
    P = sps.csr_array(sps.random(20, 12, density=0.3, rng=rng, format="csr"))
    P.indices = P.indices.astype(np.int32)
    P.indptr = P.indptr.astype(np.int32)
    for columns in (np.arange(3, 9), rng.permutation(12)[:7], np.zeros(0, np.int64)):
        assert same(_columns(P, columns), P[:, columns].tocsr())
