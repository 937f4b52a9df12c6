"""Planned sparse products (stw_tui/sos/products.py) are scipy's products bit for bit: the same
values, the same stored entries in the same order, so no downstream result can change."""

import numpy as np
import pytest
import scipy.sparse as sps

from conftest import SESSIONS
from stw_tui.session.session import Session
from stw_tui.sos.backend import SolverState
from stw_tui.sos.products import GramPlan, ProductPlan
from stw_tui.sos.window import HESSIAN_PLAN_AFTER, WindowProblem


def same(a, b) -> bool:
    return (a.shape == b.shape and np.array_equal(a.indptr, b.indptr)
            and np.array_equal(a.indices, b.indices) and np.array_equal(a.data, b.data))


def random_csr(rng, shape, zeros=0.0):
    m = sps.random_array(shape, density=rng.random() * 0.5, rng=rng, format="csr")
    m.sum_duplicates()
    m = sps.csr_array((m.data[:m.nnz].copy(), m.indices[:m.nnz].copy(), m.indptr.copy()), shape=shape)
    m.data[rng.random(m.nnz) < zeros] = 0.0   # stored zeros, as B-spline basis rows have
    return m


@pytest.mark.parametrize("fixed", ["A", "B"])
def test_a_plan_is_the_product_with_stored_zeros_and_unsorted_rows(fixed):
    rng = np.random.default_rng(1)
    for _ in range(150):
        m, k, n = (int(x) for x in rng.integers(0, 20, size=3))
        A, B = random_csr(rng, (m, k), 0.3), random_csr(rng, (k, n), 0.3)
        if A.nnz and rng.random() < 0.5:
            A = A @ random_csr(rng, (k, k))     # a product's rows are stored unsorted
        plan = ProductPlan(A, B, fixed)
        for _ in range(3):
            varying = B if fixed == "A" else A
            values = rng.standard_normal(varying.nnz) * (rng.random(varying.nnz) < 0.8)
            A2, B2 = (A, sps.csr_array((values, B.indices, B.indptr), shape=B.shape)) if fixed == "A" \
                else (sps.csr_array((values, A.indices, A.indptr), shape=A.shape), B)
            assert same(plan.matrix(plan.data(values)), A2 @ B2)


def test_a_chain_of_plans_is_the_chain_of_products_when_the_first_drops_zeros():
    rng = np.random.default_rng(2)
    for _ in range(150):
        m, k, l, n = (int(x) for x in rng.integers(1, 20, size=4))
        P, D, Q = random_csr(rng, (m, k), 0.2), random_csr(rng, (k, l)), random_csr(rng, (l, n), 0.2)
        left = ProductPlan(P, D, "A")
        X = sps.csr_array((np.ones(left.indices.size), left.indices, left.indptr), shape=left.shape)
        right = ProductPlan(X, Q, "B")
        values = rng.standard_normal(D.nnz) * (rng.random(D.nnz) < rng.random())
        x = left.data(values)
        want = P @ sps.csr_array((values, D.indices, D.indptr), shape=D.shape) @ Q
        order = right.touch_order(x == 0, rounds=10**6)
        assert same(right.matrix(right.data(x), order), want)
        if right.touch_order(x == 0, rounds=1) is False:   # the fallback: the compacted product
            assert same(left.matrix(x) @ Q, want)


def test_a_gram_plan_is_scipys_weighted_gram_matrix():
    rng = np.random.default_rng(4)
    for _ in range(150):
        m, n = (int(x) for x in rng.integers(0, 20, size=2))
        J = random_csr(rng, (m, n))
        if J.nnz and rng.random() < 0.5:
            J = J @ random_csr(rng, (n, n))     # unsorted rows
            J = sps.csr_array((J.data[:J.nnz], J.indices[:J.nnz], J.indptr), shape=J.shape)
        plan = GramPlan(J)
        values = rng.standard_normal(J.nnz) * (rng.random(J.nnz) < 0.8)
        c = rng.random(m) * (rng.random(m) < 0.9)
        J2 = sps.csr_array((values.copy(), J.indices.copy(), J.indptr.copy()), shape=J.shape)
        J2.eliminate_zeros()      # scipy's J has no stored zeros; the plan sees them as values
        assert same(plan.matrix(values, c), sps.csr_array(J2.T @ (sps.diags_array(c) @ J2)))


def test_the_window_problem_assembles_what_plain_sparse_products_give():
    session = Session()
    lines = (SESSIONS / "arm_throw.stw").read_text().splitlines()
    session.run_text("\n".join(lines[:max(i for i, x in enumerate(lines) if x.startswith("iterate"))]))
    problem = WindowProblem(session.scene)
    rng = np.random.default_rng(3)
    s = SolverState.start(problem).s
    for _ in range(HESSIAN_PLAN_AFTER + 2):
        ev = problem.evaluate(s)
        for kind, J in (("eq", ev.J_eq), ("ge", ev.J_ge)):
            rows, cols = problem._g_pattern[kind]
            G = sps.csr_array((_gradients(problem, ev, kind), (rows, cols)),
                              shape=(problem.row_counts[kind], problem.n_slots))
            assert same(J, G @ problem.Pf)
        lam_eq = rng.standard_normal(ev.c_eq.size) * (rng.random(ev.c_eq.size) < 0.7)
        lam_ge = -rng.random(ev.c_ge.size)
        H, GN = ev.lagrangian_hessian(lam_eq, lam_ge), ev.gauss_newton()
        plans, problem._product_plans = problem._product_plans, {}
        uses, problem._uses = problem._uses, {"hess": -10**9, "gram": -10**9}   # the plain route
        ev._gauss_newton = None
        assert same(GN, ev.gauss_newton())
        assert same(H, ev.lagrangian_hessian(lam_eq, lam_ge))
        problem._product_plans, problem._uses = plans, uses
        s = s + 0.01 * rng.standard_normal(s.size)
    assert problem._product_plans.get("hess") is not None and problem._product_plans.get("gram") is not None


def _gradients(problem, ev, kind):
    v = problem._slot_values(ev.s)
    parts = []
    for group in problem.groups:
        if group.kind == kind:
            _, grad, _ = group.term.full(problem._group_inputs(group, v), group.times, group.params)
            parts.append((grad * group.weights[:, None]).T.ravel())
    return np.concatenate(parts) if parts else np.zeros(0)


def test_a_new_window_on_the_same_structure_uses_the_plans_made_before_and_gets_the_same_products():
    session = Session()
    lines = (SESSIONS / "arm_throw.stw").read_text().splitlines()
    session.run_text("\n".join(lines[:max(i for i, x in enumerate(lines) if x.startswith("iterate"))]))
    first = WindowProblem(session.scene)
    s = SolverState.start(first).s
    for _ in range(HESSIAN_PLAN_AFTER + 1):
        ev = first.evaluate(s)
        ev.lagrangian_hessian(np.ones(ev.c_eq.size), -np.ones(ev.c_ge.size))
    assert first._plan_set().get("hess") is not None
    again = WindowProblem(session.scene)              # what the next `iterate` builds
    assert again._plan_set() is first._plan_set()
    rng = np.random.default_rng(5)
    ev = again.evaluate(s + 0.01 * rng.standard_normal(s.size))
    lam_eq, lam_ge = rng.standard_normal(ev.c_eq.size), -rng.random(ev.c_ge.size)
    H = ev.lagrangian_hessian(lam_eq, lam_ge)         # on the kept plan, at its first use
    again._product_plans, again._uses = {}, {"hess": -10**9, "gram": -10**9}   # the plain route
    ev._gauss_newton = None
    assert same(H, ev.lagrangian_hessian(lam_eq, lam_ge))
    session.execute("constraint extra: BX = 0 @ 0.25")   # another structure: other plans
    assert WindowProblem(session.scene)._plan_set() is not first._plan_set()


def test_grouping_is_the_stable_argsort_for_narrow_and_wide_keys():
    """Plans group product terms by output entry in the stable order of their keys, with each
    group's start: the combined-integer sort and its fallback for keys too wide to share 63 bits
    with the positions both give numpy's stable argsort exactly."""
    from stw_tui.sos.products import _grouped

    rng = np.random.default_rng(11)
    for key in (rng.integers(0, 50, 1000), np.sort(rng.integers(0, 10**6, 5000)) // 3,
                rng.integers(0, 2**55, 300), np.zeros(0, dtype=np.int64)):
        key = key.astype(np.int64)
        order, start = _grouped(key)
        want = np.argsort(key, kind="stable")
        assert np.array_equal(order, want)
        assert np.array_equal(start, np.flatnonzero(np.diff(key[want], prepend=-1)))
