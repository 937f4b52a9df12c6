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


AFFINE_SCENES = {**SCENES, "affine objective and bounds": (
    "time 0 2 knots=10\ndof x lo=-1 hi=3\ndof y\nconstraint a: x - 2*y + t = 0.5 on [0.2, 1.8]\n"
    "constraint b: x = 1, y' = 0 @ 2\nobjective o: x'' - y + sin(t)\n")}


@pytest.mark.parametrize("text", AFFINE_SCENES.values(), ids=AFFINE_SCENES.keys())
def test_affine_groups_evaluated_together_give_each_groups_own_numbers(text):
    # The affine groups' values come from one product (affine_rows.py) and their Jacobian values
    # from the first evaluation; every group computed on its own by its compiled term, and the
    # Jacobians assembled from scratch as G Pf, must give the same numbers.
    from stw_tui.sym.kinds import TermKind

    session = Session()
    session.run_text(text)
    problem = WindowProblem(session.scene)
    assert any(g.term.affine for g in problem.groups)
    rng = np.random.default_rng(5)
    for _ in range(3):
        s = problem.initial() + rng.normal(size=problem.n_free)
        ev, merit = problem.evaluate(s), problem.merit_values(s)
        v = problem._slot_values(s)
        objective, rows = 0.0, {TermKind.EQ: [], TermKind.GE: []}
        G = {kind: np.zeros((problem.row_counts[kind], problem.n_slots)) for kind in TermKind}
        for group in problem.groups:
            f, grad, _ = group.term.full(problem._group_inputs(group, v), group.times, group.params)
            weights = group.weights if group.kind != TermKind.OBJ else np.ones(group.n)
            for a in range(group.term.k):
                G[group.kind][group.row_offset + np.arange(group.n),
                              group.slot_offset + a * group.n + np.arange(group.n)] = weights * grad[:, a]
            if group.kind == TermKind.OBJ:
                objective += float(group.weights @ (f * f))
            else:
                rows[group.kind].append(group.weights * f)
        for values in (ev, merit):
            assert values.objective == pytest.approx(objective, rel=1e-14, abs=1e-14)
            for kind, c in ((TermKind.EQ, values.c_eq), (TermKind.GE, values.c_ge)):
                assert np.allclose(c, np.concatenate(rows[kind] or [np.zeros(0)]), rtol=1e-14, atol=1e-14)
        for kind, J in ((TermKind.EQ, ev.J_eq), (TermKind.GE, ev.J_ge)):
            assert np.allclose(J.toarray(), G[kind] @ problem.Pf.toarray(), rtol=1e-14, atol=1e-14)


def test_the_jacobian_of_rows_that_are_all_affine_is_made_once():
    session = Session()
    session.run_text(SCENES["pendulum"])     # boundary conditions: affine; the effort: not
    problem = WindowProblem(session.scene)
    s = problem.initial()
    first, second = problem.evaluate(s), problem.evaluate(s + 0.1)
    assert second.J_eq is first.J_eq
    assert not np.array_equal(first.c_eq, second.c_eq)
    assert not np.array_equal(first.gradient, second.gradient)


@pytest.mark.parametrize("line,label,what,time", [
    ("constraint c: x/(t - 1) = 0 @ 1", "c", "its value", 1.0),        # affine, its coefficient infinite
    ("constraint c: sqrt(x) = 1 @ 0.5", "c", "its derivative", 0.5),   # sqrt'(0)
    ("constraint c: x - 1 = 0 @ 0.5\nconstraint d: log(x - 1) = 0 @ 0.25", "d", "its value", 0.25),
])
def test_a_start_where_a_term_is_undefined_is_refused_with_its_name_and_time(line, label, what, time):
    # The check before a solve reads the affine groups from their one product, the others from
    # their compiled terms; either way the first undefined group, instance and part is named.
    from stw_tui.sym.errors import StwError

    session = Session()
    session.run_text(f"time 0 1 knots=4\ndof x\n{line}\nobjective o: x''\n")
    problem = WindowProblem(session.scene)
    group, i, found = problem.first_undefined(problem.initial())
    assert (group.label, found, group.times[i]) == (label, what, time)
    before = session.scene.coefficient_vector().copy()
    with pytest.raises(StwError, match=f"constraint {label}: {what} is not a finite real number at t={time:g}"):
        session.execute("iterate 5")
    assert np.array_equal(session.scene.coefficient_vector(), before)


def test_affine_rows_leave_a_group_with_an_undefined_coefficient_to_its_compiled_term():
    from stw_tui.sos.affine_rows import AffineRows

    session = Session()
    session.run_text("time 0 1 knots=4\ndof x\nconstraint c: x/(t - 1) = 0 @ 1\n"
                     "constraint d: 2*x' = 1 @ 0\nobjective o: x''\n")
    problem = WindowProblem(session.scene)
    affine = AffineRows(problem.groups, problem.n_slots)
    spans = {g.label: span for g, span in zip(problem.groups, affine.span)}
    assert problem.groups[0].term.affine and spans["c"] is None and spans["d"] == (0, 1)
    v = problem._slot_values(problem.initial() + 0.5)
    d = next(g for g in problem.groups if g.label == "d")
    assert affine.values(v)[0] == d.term.value(problem._group_inputs(d, v), d.times, d.params)[0]
