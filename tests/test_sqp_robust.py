"""Robust SQP steps: inconsistent linearizations (elastic mode), a step limit, conflicting
constraints named, and the same steps on every backend's linear algebra.

The step limit (``trust``) is on by default (0.5: no control point moves by more than half of
max(1, largest control point) in one step at first; the limit adapts by the merit's ratio test);
the objective-growth bound (``growth``) is an option.
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import catalogue
from conftest import ROOT, SESSIONS
from stw_tui.session.session import Session
from stw_tui.sos.backend import SolverState, Status, run_iterations
from stw_tui.sos.window import WindowProblem

sys.path.insert(0, str(ROOT / "backends"))
from stw_scipy import ScipyBackend  # noqa: E402

ARM = """
time 0 2 knots=24
const g = 9.81
linkage arm base=fixed
  S revolute a=0.5 theta=-pi/2 mass=1.0
  E revolute a=0.4 mass=0.7
end
dof S = pi*t/2
constraint start: S = 0, E = 0, S' = 0, E' = 0 @ 0
constraint end: S = pi, E = 0, S' = 0, E' = 0 @ 2
constraint reach: arm.tip.x <= 0.6 on [0, 2]
objective effort: tau_S, tau_E
"""

SINE = """
time 0 1 knots=12
dof x = 1.4 + 0.1*t
constraint c: sin(x) <= 0.5 on [0, 1]
objective o: x''
"""

CONFLICT = """
time 0 1 knots=12
dof x
constraint a: x = 1 @ 0.5
constraint b: x <= 0 on [0, 1]
objective o: x''
"""

LIMITED = "trust=0.3 growth=10"


def _solve(text: str, backend: str, n: int) -> Session:
    session = Session()
    session.run_text(f"backend {backend}\n{text}iterate {n}\n")
    return session


@pytest.fixture(scope="module")
def ipopt_objectives():
    pytest.importorskip("casadi")
    return {name: _solve(text, "ipopt", 500).runs[-1].reports[-1].objective
            for name, text in (("arm", ARM), ("sine", SINE))}


@pytest.mark.parametrize("backend", ["scipy", "torch device=cpu"])
@pytest.mark.parametrize("name", ["arm", "sine"])
def test_reproductions_converge_at_least_as_low_as_ipopt(ipopt_objectives, backend, name):
    if backend.startswith("torch"):
        pytest.importorskip("torch")
    text = {"arm": ARM, "sine": SINE}[name]
    run = _solve(text, f"{backend} {LIMITED}", 100).runs[-1]
    assert run.status is Status.CONVERGED, run.status
    last = run.reports[-1]
    assert last.max_violation <= 1e-8
    assert last.objective <= ipopt_objectives[name] * (1 + 1e-6) + 1e-10


@pytest.mark.parametrize("backend", ["scipy", "torch device=cpu"])
def test_reproductions_converge_with_the_default_step_limit(ipopt_objectives, backend):
    # Without a step limit the arm blew up (objective 8e86, then "line search failed"; torch ran
    # 100 iterations to 1e33) and sin(x) <= 0.5 ended in overflow and a singular KKT system.
    if backend.startswith("torch"):
        pytest.importorskip("torch")
    arm = _solve(ARM, backend, 100).runs[-1]
    assert arm.status is Status.CONVERGED and arm.reports[-1].max_violation <= 1e-8
    # IPOPT's optimum or a lower one (3.14 against 5.30 today), and no blow-up on the way.
    assert arm.reports[-1].objective <= ipopt_objectives["arm"] * (1 + 1e-6)
    assert max(r.objective for r in arm.reports) <= 1e3
    sine = _solve(SINE, backend, 50).runs[-1]
    assert sine.status is Status.CONVERGED
    assert sine.reports[-1].objective <= ipopt_objectives["sine"] + 1e-10


def test_conflicting_constraints_are_named():
    session = Session()
    session.run_text(CONFLICT)
    outcome = session.execute("iterate 50")
    assert "a and b conflict" in outcome.message       # the console says which constraints
    run = session.runs[-1]
    assert run.status is Status.INFEASIBLE
    last = run.reports[-1]
    assert last.infeasible and set(last.conflicts) == {"a", "b"}
    assert "a and b" in last.message and last.elastic


def test_conflicting_equality_rows_alone_leave_the_one_kkt_solve_for_elastic_mode_and_are_named():
    """Without inequality rows a step is one KKT solve (SQPBackend._equality_qp); rows it cannot
    meet (x = 1 and x = 0 at one instant) send the step to the general path, whose elastic QP
    cannot lower their violation even to first order: a conflict (solver._no_progress)."""
    session = Session()
    session.run_text("time 0 1 knots=12\ndof x\nconstraint a: x = 1 @ 0.5\n"
                     "constraint b: x = 0 @ 0.5\nobjective o: x''")
    outcome = session.execute("iterate 50")
    run = session.runs[-1]
    assert run.status is Status.INFEASIBLE
    assert run.reports[0].elastic and set(run.reports[-1].conflicts) == {"a", "b"}
    # found at once (the steps wandered between the two values for all 50 iterations), and the
    # console names the conflict instead of advising to refine the knots
    assert len(run.reports) <= 3
    assert "a and b conflict" in outcome.message and "refine the knots" not in outcome.message


def test_a_row_whose_gradient_vanishes_at_the_start_is_no_conflict():
    """x² = 1 from x = 0: the linearization 0·d = 1 cannot be met and the elastic step lowers
    its violation not at all to first order, but the objective's step leaves x = 0 and the
    violation falls in fact: that is no conflict (solver._no_progress), and the solve converges."""
    session = Session()
    session.run_text("time 0 1 knots=12\ndof x\nconstraint c: x^2 = 1 @ 0.5\nobjective o: x''\n"
                     "objective p: x - 0.3")
    session.execute("iterate 50")
    run = session.runs[-1]
    assert run.reports[0].elastic and run.status is Status.CONVERGED
    assert abs(session.scene.dofs["x"].curve.evaluate(np.array([0.5]))[0] ** 2 - 1) < 1e-8


def test_one_constraint_that_cannot_be_met_from_here_is_not_called_a_conflict():
    """x² = 1 from x = 0 with nothing to move x: no step lowers the violation. One constraint
    alone is named as not met from here, with what may move the curves, not as a conflict."""
    session = Session()
    session.run_text("time 0 1 knots=12\ndof x\nconstraint c: x^2 = 1 @ 0.5\nobjective o: x''")
    outcome = session.execute("iterate 50")
    assert session.runs[-1].status is Status.INFEASIBLE
    assert "constraint c cannot be met from here" in outcome.message and "shake" in outcome.message
    assert "constraints c conflict" not in outcome.message


def test_a_capped_interior_point_method_is_reported_and_falls_back_to_elastic():
    run = _solve(ARM, f"scipy {LIMITED}", 1).runs[-1]
    first = run.reports[0]
    assert first.qp_capped >= 1 and first.elastic


def test_an_inconsistent_linearization_stops_the_interior_point_method_soon_after_its_floor(monkeypatch):
    # d₀ = 1 and d₀ = 2: the stabilized rows meet halfway, d₀ = 1.5, through multipliers
    # ±0.5/ε = 5e9. The dual residual's rounding floor (|y| eps) is far above IPM_TOL; after
    # INFEASIBLE_STALL iterations there instead of IPM_STALL the method stops with the same step
    # (which the SQP refuses for the elastic QP, whose weight is capped at INFEASIBLE_MULTIPLIER).
    import scipy.sparse as sps
    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp import qp as Q

    monkeypatch.setattr(Q, "FLOOR_STALL", 10 ** 9)   # this rule alone (the polish would end it too)
    la = SparseAlgebra()
    H, g = sps.csr_array(np.eye(2)), np.array([0.0, 1.0])
    Ae, ce = sps.csr_array([[1.0, 0.0], [1.0, 0.0]]), np.array([-1.0, -2.0])
    Ai, ci = sps.csr_array([[0.0, 1.0]]), np.array([0.5])
    soon = Q.solve_qp(la, H, g, Ae, ce, Ai, ci)
    saved = Q.IPM_STALL - Q.INFEASIBLE_STALL
    monkeypatch.setattr(Q, "INFEASIBLE_STALL", Q.IPM_STALL)
    late = Q.solve_qp(la, H, g, Ae, ce, Ai, ci)
    assert late.ipm_iterations - soon.ipm_iterations == saved
    np.testing.assert_allclose(soon.d, [1.5, -0.5], atol=1e-9)      # d₁ at its bound -0.5
    np.testing.assert_allclose(soon.d, late.d, atol=1e-12)
    assert np.abs(soon.y).max() >= Q.INFEASIBLE_MULTIPLIER


def test_a_hard_qp_at_its_rounding_floor_is_polished_there_not_after_stalling(monkeypatch):
    # A hard QP of luxo.stw's (185 variables, 110 equality and 256 inequality rows) whose
    # interior-point iterates reach their rounding floor short of IPM_TOL. Polished on the rows
    # that bind (z > w) after FLOOR_STALL stalled iterations, it ends with exactly the answer it
    # reached after IPM_STALL of them (the polish depends on those rows alone), and that answer
    # meets the QP's KKT conditions.
    import scipy.sparse as sps
    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp import qp as Q

    f = np.load(ROOT / "tests" / "data" / "luxo_floor_qp.npz")

    def matrix(name):
        return sps.csr_array((f[name + "_data"], f[name + "_indices"], f[name + "_indptr"]),
                             shape=tuple(f[name + "_shape"]))

    H, Ae, Ai, g, ce, ci, y0 = matrix("H"), matrix("Ae"), matrix("Ai"), f["g"], f["ce"], f["ci"], f["y0"]
    # The floor is SuperLU's rounding (the banded LU's reaches IPM_TOL on this QP in 13 iterations)
    crossed = Q.solve_qp(SparseAlgebra(factor="superlu"), H, g, Ae, ce, Ai, ci, y0=y0)
    monkeypatch.setattr(Q, "CROSSOVER_ERROR", -1.0)   # this rule alone (the crossover ends it sooner)
    soon = Q.solve_qp(SparseAlgebra(factor="superlu"), H, g, Ae, ce, Ai, ci, y0=y0)
    # The rows it crosses over to are the ones it would have polished at the floor: the same answer
    assert crossed.ipm_iterations < soon.ipm_iterations
    for a, b in ((crossed.d, soon.d), (crossed.y, soon.y), (crossed.z, soon.z)):
        np.testing.assert_array_equal(a, b)
    monkeypatch.setattr(Q, "FLOOR_STALL", 10 ** 9)
    late = Q.solve_qp(SparseAlgebra(factor="superlu"), H, g, Ae, ce, Ai, ci, y0=y0)
    assert soon.ipm_iterations + 10 <= late.ipm_iterations
    for a, b in ((soon.d, late.d), (soon.y, late.y), (soon.z, late.z)):
        np.testing.assert_array_equal(a, b)
    d, y, z = soon.d, soon.y, soon.z
    slack = Ai @ d + ci
    scale = 1.0 + np.abs(g).max()
    assert np.abs(H @ d + g + Ae.T @ y - Ai.T @ z).max() <= 1e-9 * scale
    assert np.abs(Ae @ d + ce).max() <= 1e-10 * (1.0 + np.abs(ce).max())
    assert slack.min() >= -1e-12 and z.min() >= 0.0 and np.abs(z * slack).max() <= 1e-9 * scale


def _sole_qp():
    """A hard QP of the acrobat's ballistic phase with a 30 cm sole (support=[-0.15, 0.15]): 376
    variables, 90 equality and 1551 inequality rows, recorded with the multipliers it was warm
    started from: those of an elastic step, |y0| up to 1.6e7 (IPOPT solves the same QP with
    |y| <= 2.8e4)."""
    import scipy.sparse as sps
    f = np.load(ROOT / "tests" / "data" / "acrobat_sole_qp.npz")

    def matrix(name):
        return sps.csr_array((f[name + "_data"], f[name + "_indices"], f[name + "_indptr"]),
                             shape=tuple(f[name + "_shape"]))
    return matrix("H"), f["g"], matrix("Ae"), f["ce"], matrix("Ai"), f["ci"], f["y0"], f["z0"]


def test_a_hard_qp_warm_started_on_an_elastic_steps_multipliers_solves_from_cold():
    # Stabilized around multipliers of 1.6e7, the interior-point method follows two nearly
    # dependent rows' multipliers out there and stalls (capped); from zero the same QP solves,
    # and its answer meets the KKT conditions of the QP (convex: H is positive definite).
    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp import qp as Q

    H, g, Ae, ce, Ai, ci, y0, z0 = _sole_qp()
    assert np.linalg.eigvalsh(H.toarray()).min() > 0
    warm = Q.solve_qp(SparseAlgebra(), H, g, Ae, ce, Ai, ci, y0=y0, z0=z0, convex=True)
    assert warm.capped                       # the failure the SQP works around
    cold = Q.solve_qp(SparseAlgebra(), H, g, Ae, ce, Ai, ci, convex=True)
    assert not cold.capped
    d, y, z = cold.d, cold.y, cold.z
    scale = 1.0 + np.abs(g).max()
    slack = Ai @ d + ci
    assert np.abs(H @ d + g + Ae.T @ y - Ai.T @ z).max() <= 1e-8 * scale
    # its equality rows are stabilized (Ae d + ce = ε y, solve_qp): met up to 1e-3 of their
    # violation, as the SQP asks of a hard step
    assert np.abs(Ae @ d + ce - Q.KKT_EPS * y).max() <= 1e-6 * np.abs(ce).max()
    assert np.abs(Ae @ d + ce).max() <= 1e-3 * np.abs(ce).max() and slack.min() >= -1e-10
    assert z.min() >= 0.0 and np.abs(z * slack).max() <= 1e-8 * scale
    assert np.abs(y).max() <= 1e5               # IPOPT's multipliers on it: |y| <= 2.8e4


def test_the_sqp_takes_the_hard_step_a_warm_start_could_not_find():
    # The same QP as the SQP's subproblem: it tries the warm-started hard QP, then the cold one,
    # and only then the elastic QP. The step it returns is the cold QP's, which meets the rows.
    from types import SimpleNamespace

    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp import solver as S

    H, g, Ae, ce, Ai, ci, y0, z0 = _sole_qp()
    la = SparseAlgebra()
    ev = SimpleNamespace(s=np.zeros(g.size), gradient=g, c_eq=ce, c_ge=ci)
    lin = S._Linearization(np.arange(ce.size), np.arange(ci.size), g, Ae, ce, Ai, ci, y0, -z0,
                           np.zeros(ci.size, bool))
    counts = S._Counts()
    sub, _rho = ScipyBackend()._subproblem(la, H, ev, lin, 0.0, {"tol_violation": 1e-8}, counts, convex=True)
    assert not counts.elastic and sub.qp.elastic is None and not sub.qp.capped
    assert np.abs(Ae @ sub.d + ce).max() <= 1e-3 * np.abs(ce).max() and (Ai @ sub.d + ci).min() >= -1e-10


def _sketched_throw() -> str:
    text = (SESSIONS / "arm_throw.stw").read_text()
    head = text[:text.index("iterate 150")]
    return head + ("key 0.3 SHOULDER=-2.2 ELBOW=0.3 WRIST=0.2\n"
                   "key 0.55 SHOULDER=-0.6 ELBOW=0.2 WRIST=0.1\n"
                   "key 1.0 SHOULDER=0.2 ELBOW=0.1 WRIST=0\n"
                   "key 1.5 SHOULDER=0.3 ELBOW=0 WRIST=0\n"
                   "key 0.55 BX=0.7 BY=-0.1\n")


def test_no_step_multiplies_the_objective_by_more_than_100_on_the_sketched_throw():
    setup = Session()
    setup.run_text(_sketched_throw())
    problem = WindowProblem(setup.scene)
    start = SolverState.start(problem)
    objective = problem.evaluate(start.s).objective
    result = run_iterations(ScipyBackend(trust=0.3, growth=10), problem, start, 150, setup.scene.settings)
    assert result.converged
    for report in result.reports:
        assert report.objective <= 100 * max(objective, 1.0)
        objective = report.objective


def test_torch_takes_the_same_first_step_as_scipy():
    torch = pytest.importorskip("torch")  # noqa: F841
    from stw_torch import TorchBackend

    setup = Session()
    setup.run_text(SINE)
    problem = WindowProblem(setup.scene)
    start = SolverState.start(problem)
    for options in ({}, {"trust": 0.3}):
        ref = run_iterations(ScipyBackend(**options), problem, start, 1, setup.scene.settings)
        for linear in ("scipy", "torch"):
            got = run_iterations(TorchBackend(device="cpu", linear=linear, **options), problem, start, 1,
                                 setup.scene.settings)
            assert np.abs(got.state.s - ref.state.s).max() <= 1e-8
            # (Whether the interior-point method reached 1e-11 before its cap may differ between
            # a sparse and a dense factorization; the step may not.)
            assert got.reports[0].objective == pytest.approx(ref.reports[0].objective, rel=1e-8, abs=1e-12)


def test_kkt_matrix_is_block_arrays_entry_for_entry_through_its_cached_layouts():
    """The KKT matrix placed in CSC directly (with placements kept per sparsity structure) holds
    exactly what ``block_array`` builds: the same entries, stored zeros and order, so SuperLU
    factorizes the same matrix and the iterates do not change."""
    import scipy.sparse as sps
    from stw_scipy.linear import kkt_matrix

    def block(H, A, e):
        E = sps.diags_array(np.broadcast_to(np.asarray(e, float), (A.shape[0],)))
        return sps.block_array([[H, A.T], [A, -E]], format="csc")

    rng = np.random.default_rng(7)
    structures = []
    for _ in range(4):
        n, m = int(rng.integers(1, 30)), int(rng.integers(1, 20))
        H = sps.random_array((n, n), density=0.3, rng=rng, format="csr")
        H = sps.csr_array(H + H.T) if len(structures) % 2 else sps.csr_array(H @ H.T)   # rows unsorted
        structures.append((H, sps.random_array((m, n), density=0.3, rng=rng, format="csr")))
    layouts: list = []
    for _ in range(60):
        H, A = (M.copy() for M in structures[int(rng.integers(len(structures)))])
        H.data[:] = rng.standard_normal(H.nnz) * (rng.random(H.nnz) < 0.9)   # some stored zeros
        A.data[:] = rng.standard_normal(A.nnz)
        m = A.shape[0]
        e = 1e-10 if rng.random() < 0.5 else rng.random(m) * (rng.random(m) < 0.8)   # zeros left out
        got, want = kkt_matrix(H, A, e, layouts), block(H, A, e)
        assert np.array_equal(got.indptr, want.indptr) and np.array_equal(got.indices, want.indices)
        assert np.array_equal(got.data, want.data)
    assert 0 < len(layouts) <= 8


def test_sparse_gram_and_transposed_products_are_scipys_bit_for_bit():
    """The interior-point method's Aᵀ diag(w) A (planned once per structure of A) and Aᵀ x (with
    the transpose kept) are exactly what the plain scipy expressions give."""
    import scipy.sparse as sps
    from stw_scipy.linear import SparseAlgebra

    la, rng = SparseAlgebra(), np.random.default_rng(8)
    factors = [sps.random_array((m, 9), density=0.4, rng=rng, format="csr") for m in (0, 3, 7, 12, 5)]
    for k in range(60):
        A = factors[k % len(factors)].copy()
        A.data = rng.standard_normal(A.nnz) * (rng.random(A.nnz) < 0.9)
        w = rng.random(A.shape[0])
        got, want = la.gram(A, w), sps.csr_array(A.T @ (sps.diags_array(w) @ A))
        assert np.array_equal(got.indptr, want.indptr) and np.array_equal(got.indices, want.indices)
        assert np.array_equal(got.data, want.data)
        x = rng.standard_normal(A.shape[0])
        assert np.array_equal(la.rmatvec(A, x), A.T @ x)


def _random_qp_parts(rng):
    """H (symmetric, rows unsorted as the SQP's sums leave them), Aᵢ and Aₑ of random sizes."""
    import scipy.sparse as sps

    n, me, mi = int(rng.integers(2, 25)), int(rng.integers(0, 8)), int(rng.integers(1, 12))
    H = sps.random_array((n, n), density=0.3, rng=rng, format="csr")
    H = sps.csr_array(H + H.T + sps.eye_array(n))
    Ai = sps.random_array((mi, n), density=0.3, rng=rng, format="csr")
    Ae = sps.random_array((me, n), density=0.4, rng=rng, format="csr")
    return H, Ai, Ae


@pytest.mark.parametrize("factor", ["superlu", "auto"])
def test_interior_point_kkt_scattered_in_place_is_the_assembled_one_bit_for_bit(factor):
    """The interior-point systems scattered into a structure placed once per QP (BarrierKKT) hold
    exactly what the general assembly kkt_matrix(H + gram(Aᵢ, q), Aₑ, e) builds, also when an
    entry of H + Gram cancels to zero (the sum drops it) or H stores an explicit zero; and they
    solve as a factorization of that K made afresh does (splu(K, COLAMD); by default, the banded
    LU where K is a narrow band), also once factorized from their values alone (ReplayedKKT)."""
    import scipy.sparse as sps
    import scipy.sparse.linalg as spla
    from stw_scipy.linear import SparseAlgebra, kkt_matrix
    from stw_scipy.ordering import factorize

    la, rng = SparseAlgebra(factor=factor), np.random.default_rng(9)
    for k in range(40):
        H, Ai, Ae = _random_qp_parts(rng)
        n, me, mi = H.shape[0], Ae.shape[0], Ai.shape[0]
        if k % 4 == 1:
            H.data[0] = 0.0                               # a stored zero of H
        system = la.barrier_kkt(H, Ai, Ae)
        for _ in range(3):
            q = rng.random(mi)
            e = 1e-10 + rng.random(me)
            G = la.gram(Ai, q)
            if k % 4 == 2 and G.nnz:                      # an entry of H + Gram that cancels
                i = int(np.flatnonzero(np.diff(G.indptr))[0])
                j = int(G.indices[G.indptr[i]])
                H = H.tolil()
                H[i, j] = -G[i, j]
                H = sps.csr_array(H)
                system = la.barrier_kkt(H, Ai, Ae)
            want = kkt_matrix(la.add(H, G), Ae, e)
            scattered = system(q, e)   # from the second on: factorized on the replayed ordering
            got = scattered.K
            assert np.array_equal(got.indptr, want.indptr) and np.array_equal(got.indices, want.indices)
            assert np.array_equal(got.data, want.data)
            b = rng.standard_normal(n + me)
            fresh = factorize(want, [], band_max=la.band_max).solve(b)
            assert np.array_equal(scattered.solve(b), fresh)
            if factor == "superlu":
                assert np.array_equal(fresh, spla.splu(want, permc_spec="COLAMD").solve(b))


@pytest.mark.parametrize("factor", ["superlu", "auto"])
def test_working_set_kkt_masked_from_all_rows_is_the_assembled_one_bit_for_bit(factor):
    """A working set's system masked out of K with every inequality row (WorkingSetKKT, its
    layout kept per structure of H, Aₑ and Aᵢ) holds exactly what kkt_matrix builds from the
    stacked rows, for any set of rows, none and all included; it solves as that K factorized
    afresh; and where kkt_matrix would sum a repeated entry, or e = 0 leaves the diagonal out,
    the general assembly is used."""
    import scipy.sparse as sps
    from stw_scipy.csr_rows import select_rows, stack_rows
    from stw_scipy.linear import SparseAlgebra, kkt_matrix
    from stw_scipy.ordering import factorize
    from stw_tui.sos.sqp.algebra import SingularSystem

    la, rng = SparseAlgebra(factor=factor), np.random.default_rng(11)
    for k in range(30):
        H, Ai, Ae = _random_qp_parts(rng)
        mi = Ai.shape[0]
        if k % 5 == 3 and Ai.nnz:                         # a row storing one entry twice
            r = int(np.flatnonzero(np.diff(Ai.indptr))[0])
            at = int(Ai.indptr[r])
            indptr = Ai.indptr.copy()
            indptr[r + 1:] += 1
            Ai = sps.csr_array((np.insert(Ai.data, at, 1.0), np.insert(Ai.indices, at, Ai.indices[at]),
                                indptr), shape=Ai.shape)
        e = 0.0 if k % 5 == 4 else 1e-10
        systems = la.working_set_kkt(H, Ae, Ai, e)
        if k % 5 == 3 and Ai.nnz:
            assert systems.placed is None
        for binding in (np.zeros(mi, bool), np.ones(mi, bool), rng.random(mi) < 0.5, rng.random(mi) < 0.5):
            want = kkt_matrix(H, stack_rows([Ae, select_rows(Ai, np.flatnonzero(binding))]), e)
            try:
                fresh = factorize(want, [], band_max=la.band_max)
            except RuntimeError:   # exactly singular (e = 0 and dependent rows): so is the masked one
                with pytest.raises(SingularSystem):
                    systems(binding)
                continue
            got = systems(binding)
            assert np.array_equal(got.K.indptr, want.indptr) and np.array_equal(got.K.indices, want.indices)
            assert np.array_equal(got.K.data, want.data)
            b = rng.standard_normal(want.shape[0])
            assert np.array_equal(got.solve(b), fresh.solve(b))


def test_a_bound_against_a_constraint_is_infeasible_and_names_both():
    # The hard QP "converged" here with huge multipliers (its equality rows are regularized) to a
    # step that does not meet the linearization; the line search then failed and the advice was
    # "try shake". Now the step is refused, the elastic QP is used, and the conflict is named.
    s = Session()
    s.run_text("time 0 1 knots=8\ndof x lo=0\nconstraint c: x = -1 @ 0.5\nobjective o: x''\n")
    outcome = s.execute("iterate 30")
    run = outcome.run
    assert run.status is Status.INFEASIBLE
    assert set(run.reports[-1].conflicts) == {"c", "x.bounds"}
    assert "c and x.bounds conflict" in outcome.message and "shake" not in outcome.message


def test_an_elastic_qp_with_a_large_weight_keeps_its_best_acceptable_iterate():
    # The first QP of a hop (the acrobat's contact and flight verbs, 132 control points, saved
    # from a real solve) has an inconsistent linearization. Its elastic QP with ρ = 1e6 reaches
    # scaled residuals near 1e-9 after ~35 interior-point iterations; then round-off throws the
    # iterates off and they never reach IPM_TOL. It used to run to IPM_MAX and return that
    # thrown-off last iterate, reported as capped. Checked here from the definition: the
    # ℓ1-elastic QP min ½dᵀHd + gᵀd + ρ(Σ|A_e d + c_e| + Σ max(0, -(A_i d + c_i))) is convex, and
    # d is its minimizer iff multipliers with |y| <= ρ, 0 <= z <= ρ make the gradient vanish,
    # with y = ρ·sign(row) on violated equality rows, z = ρ on violated inequality rows and z = 0
    # on inactive ones.
    import scipy.sparse as sps

    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp import qp as Q

    f = np.load(ROOT / "tests" / "data" / "hop_first_qp.npz")
    H = sps.csr_array((f["H_data"], f["H_indices"], f["H_indptr"]), shape=tuple(f["H_shape"]))
    Ae, Ai, g = sps.csr_array(f["Ae"]), sps.csr_array(f["Ai"]), f["g"]
    rho = 1e6
    qp = Q.solve_qp(SparseAlgebra("direct", 1e-12, 1000), H, g, Ae, f["ce"], Ai, f["ci"], f["y0"], elastic=rho)
    assert not qp.capped and qp.ipm_iterations < Q.IPM_MAX
    d, y, z = qp.d, qp.y, qp.z
    assert np.abs(H @ d + g + Ae.T @ y - Ai.T @ z).max() <= 1e-6 * rho
    assert np.all(np.abs(y) <= rho * (1 + 1e-6)) and np.all((z >= -1e-6 * rho) & (z <= rho * (1 + 1e-6)))
    row_e, row_i = Ae @ d + f["ce"], Ai @ d + f["ci"]
    violated = np.abs(row_e) > 1e-4
    assert violated.any()                                   # the linearization is inconsistent
    np.testing.assert_allclose(y[violated], rho * np.sign(row_e[violated]), rtol=1e-3)
    np.testing.assert_allclose(z[row_i < -1e-4], rho, rtol=1e-3)
    assert np.all(np.abs(z[row_i > 1e-4]) <= 1e-3 * rho)


def test_an_elastic_qp_at_its_rounding_floor_stops_there_with_the_same_best_iterate(monkeypatch):
    # The hop's elastic QP above: once its best iterate is acceptable, FLOOR_STALL iterations
    # without progress end it; the IPM_STALL - FLOOR_STALL more it ran before found no better one.
    import scipy.sparse as sps

    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp import qp as Q

    f = np.load(ROOT / "tests" / "data" / "hop_first_qp.npz")
    H = sps.csr_array((f["H_data"], f["H_indices"], f["H_indptr"]), shape=tuple(f["H_shape"]))
    args = (H, f["g"], sps.csr_array(f["Ae"]), f["ce"], sps.csr_array(f["Ai"]), f["ci"], f["y0"])
    # (the floor of SuperLU's rounding, where the fixture was recorded)
    soon = Q.solve_qp(SparseAlgebra(factor="superlu"), *args, elastic=1e6)
    monkeypatch.setattr(Q, "FLOOR_STALL", 10 ** 9)
    late = Q.solve_qp(SparseAlgebra(factor="superlu"), *args, elastic=1e6)
    assert soon.ipm_iterations + 10 <= late.ipm_iterations and not soon.capped
    for a, b in ((soon.d, late.d), (soon.y, late.y), (soon.z, late.z)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_dependent_binding_rows_share_their_force_without_drift(la):
    # min ½dᵀHd + gᵀd with d₀ = 0 twice: as an equality row, and as a bound d₀ >= 0 that binds
    # (g₀ > 0). Only y - z = -g₀ is determined. Solved again and again from the last multipliers,
    # as the SQP does, the interior-point method's leftover slack w ≈ μ/z turned into a multiplier
    # change of w/ε each time (basketball.stw: `limit ELBOW 0 2.5` with `ELBOW = 0 @ 0`; its
    # multiplier grew from 1 to 3500 in 300 steps, and the merit weight with it).
    import scipy.sparse as sps
    from stw_tui.sos.sqp.qp import solve_qp

    H = la.matrix(sps.csr_array(np.diag([2.0, 1e4])))
    g = la.vector([30.0, -3e4])
    Ae, ce = la.matrix(sps.csr_array([[1.0, 0.0]])), la.vector([0.0])
    Ai, ci = la.matrix(sps.csr_array([[1.0, 0.0], [0.0, 1.0]])), la.vector([0.0, 2.0])
    y, z = la.zeros(1), la.zeros(2)
    seen = []
    for _ in range(30):
        qp = solve_qp(la, H, g, Ae, ce, Ai, ci, y0=y, z0=z, working=z > 0)
        y, z = qp.y, qp.z
        seen.append(float(y[0]))
    d = la.numpy(qp.d)
    assert d == pytest.approx([0.0, 3.0], abs=1e-12)      # the QP's solution: d₁ = 3e4/1e4
    assert float(y[0] - z[0]) == pytest.approx(-30.0, abs=1e-9)   # stationarity in d₀
    assert float(z[0]) >= 0 and float(z[1]) == 0.0
    # The multipliers settle (they drifted by 0.033 each solve, 1.0 in all, before).
    assert abs(seen[-1] - seen[-2]) <= 1e-12 * 30 and max(seen) - min(seen) <= 1e-5 * 30


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_positive_definite_agrees_with_the_eigenvalues(la):
    import scipy.sparse as sps

    rng = np.random.default_rng(11)
    for k in range(40):
        n = int(rng.integers(1, 25))
        B = sps.random_array((n, n), density=0.3, rng=rng).toarray()
        M = B @ B.T + np.diag(rng.random(n))                    # positive definite
        shift = np.linalg.eigvalsh(M).min() * (1 + (-1) ** k * 10 ** rng.uniform(-6, 0))
        M -= shift * np.eye(n)                                   # just above or just below zero
        want = np.linalg.eigvalsh(M).min() > 0
        assert la.positive_definite(la.matrix(sps.csr_array(M))) == want


@pytest.mark.parametrize("dense_max", [0, 10_000], ids=["sparse LDLt", "dense Cholesky"])
def test_both_positive_definite_tests_of_the_scipy_algebra_agree_with_the_eigenvalues(monkeypatch, dense_max):
    import scipy.sparse as sps

    import stw_scipy.linear as linear

    monkeypatch.setattr(linear, "DENSE_TEST_MAX", dense_max)
    la = linear.SparseAlgebra()
    rng = np.random.default_rng(5)
    for k in range(30):
        n = int(rng.integers(1, 60))
        B = sps.random_array((n, n), density=0.2, rng=rng).toarray()
        M = B @ B.T + np.diag(rng.random(n))
        M -= np.linalg.eigvalsh(M).min() * (1 + (-1) ** k * 10 ** rng.uniform(-6, 0)) * np.eye(n)
        assert la.positive_definite(la.matrix(sps.csr_array(M))) == (np.linalg.eigvalsh(M).min() > 0)
    M = np.eye(3)
    M[1, 1] = np.nan
    assert not la.positive_definite(la.matrix(sps.csr_array(M)))      # undefined is not convex


def test_convexify_shifts_just_enough_for_the_null_space_of_the_binding_rows():
    import scipy.sparse as sps
    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp.curvature import convexify

    la = SparseAlgebra()
    H = sps.csr_array(np.diag([1.0, -1.0, -100.0]))
    # On the null space of the row x₂ (span(e₀, e₁)) the least eigenvalue is -1: the shift must
    # exceed 1, and the bisections keep it within 10^(1/8) of that (the -100 along e₂ is the
    # row's business, not the model's).
    model, shift = convexify(la, H, sps.csr_array([[0.0, 0.0, 1.0]]))
    assert 1.0 < shift <= 10 ** (1 / 8) * 1.001
    assert np.linalg.eigvalsh(model.toarray()[:2, :2]).min() > 0
    # With a binding row on x₁ too, the model is convex on what is left (e₀): no shift.
    model, shift = convexify(la, H, sps.csr_array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]))
    assert shift == 0.0 and model is H
    # Without rows, the whole space: it would take 100, more than the largest shift tried
    # (SHIFT_MAX = 0.1 of the largest |H_ii|), which is what comes back.
    assert convexify(la, H, None)[1] == pytest.approx(10.0)


def test_convexify_sees_through_rows_far_narrower_than_the_widest():
    import scipy.sparse as sps
    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp.curvature import convexify

    la = SparseAlgebra()
    # The rows pin x₀ and x₁, so only e₂ is free, where H is +1: convex on the null space, no
    # shift. The row on x₁ is 1000x narrower than the one on x₀ (different units), and H is
    # -1000 along x₁: a penalty that only outweighs H on the widest row calls this indefinite.
    H = sps.csr_array(np.diag([1.0, -1000.0, 1.0]))
    A = sps.csr_array([[1.0, 0.0, 0.0], [0.0, 1e-3, 0.0]])
    model, shift = convexify(la, H, A)
    assert shift == 0.0 and model is H
    # Take the narrow row away and x₁ is free: the -1000 is then the model's, and it is shifted.
    assert convexify(la, H, sps.csr_array([[1.0, 0.0, 0.0]]))[1] > 0


@pytest.mark.parametrize("name", ["arm", "sine"])
def test_scipy_and_torch_reach_the_same_motion_on_the_reproductions(name):
    # Issue 8: the same optimum from the same start (motion difference <= 1e-5), with the default
    # step limit, on both reproductions that used to blow up.
    pytest.importorskip("torch")
    text = {"arm": ARM, "sine": SINE}[name]
    ref, got = _solve(text, "scipy", 100), _solve(text, "torch device=cpu", 100)
    assert ref.runs[-1].status is Status.CONVERGED and got.runs[-1].status is Status.CONVERGED
    ref_motion, got_motion = ref.sample(201), got.sample(201)
    assert ref_motion.keys() == got_motion.keys()
    worst = max(np.abs(np.asarray(ref_motion[d]["value"]) - np.asarray(got_motion[d]["value"])).max()
                for d in ref_motion)
    assert worst <= 1e-5, worst


def test_replayed_column_ordering_factorizes_bit_for_bit_as_colamd():
    """SuperLU's ordering of a KKT structure, worked out by the first factorization and replayed
    for the next K's of that structure (ordering.py), solves exactly as splu(K, COLAMD) does,
    pivoting included (indefinite K, tiny -ε block), and it is replayed, not recomputed."""
    import scipy.sparse as sps
    import scipy.sparse.linalg as spla
    from stw_scipy.linear import kkt_matrix
    from stw_scipy.ordering import factorize

    rng = np.random.default_rng(10)
    structures = []
    for _ in range(3):
        n, m = int(rng.integers(20, 60)), int(rng.integers(5, 20))
        H = sps.random_array((n, n), density=0.1, rng=rng, format="csr")
        structures.append((sps.csr_array(H + H.T + sps.eye_array(n)),
                           sps.random_array((m, n), density=0.15, rng=rng, format="csr")))
    orderings: list = []
    replayed = 0
    for k in range(30):
        H, A = (M.copy() for M in structures[k % len(structures)])
        H.data[:] = rng.standard_normal(H.nnz)
        A.data[:] = rng.standard_normal(A.nnz)
        K = kkt_matrix(H, A, 1e-10)
        b = rng.standard_normal(K.shape[0])
        try:
            want = spla.splu(K, permc_spec="COLAMD").solve(b)
        except RuntimeError:   # exactly singular: the replay must say so too
            with pytest.raises(RuntimeError):
                factorize(K, orderings)
            continue
        lu = factorize(K, orderings)
        replayed += lu.perm is not None
        assert np.array_equal(lu.solve(b), want)
    assert len(orderings) == len(structures) and replayed >= 20
    # The positive-definiteness test's factorization (symmetric ordering, diagonal pivots): the
    # same pivots, bit for bit, at the same places (in K's labels and in the replay's).
    spd = dict(diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    for k in range(20):
        H, A = structures[k % len(structures)]
        M = sps.csc_array(H + 3.0 * (A.T @ A))
        M.data[:] = rng.standard_normal(M.nnz)
        M = sps.csc_array(M + M.T + (4.0 if k % 2 else 0.0) * sps.eye_array(M.shape[0]))
        want = spla.splu(M, permc_spec="MMD_AT_PLUS_A", **spd)
        replay = factorize(M, orderings, "MMD_AT_PLUS_A", **spd)
        replayed += replay.perm is not None
        lu = replay.lu
        assert np.array_equal(lu.perm_r == lu.perm_c, (want.perm_r == want.perm_c)[np.argsort(want.perm_c)]) \
            if replay.perm is not None else np.array_equal(lu.perm_r, want.perm_r)
        assert np.array_equal(lu.U.diagonal(), want.U.diagonal())
    assert replayed >= 20 + 10


def test_each_backend_gives_the_rows_own_sums_of_squares():
    import scipy.sparse as sps

    from stw_scipy.dense import NumpyDenseAlgebra
    from stw_scipy.linear import SparseAlgebra

    rng = np.random.default_rng(2)
    for shape in ((1, 1), (4, 23), (40, 135), (0, 5)):
        A = sps.random_array(shape, density=0.3, rng=rng, format="csr") * 1e3
        want = (A.toarray() ** 2).sum(axis=1)
        assert np.allclose(SparseAlgebra().row_squares(A), want, rtol=1e-14, atol=0)
        assert np.allclose(NumpyDenseAlgebra().row_squares(A.toarray()), want, rtol=1e-14, atol=0)


def test_convexify_sees_a_convex_model_through_nearly_dependent_rows_of_any_scale():
    """The raw grasp's failure, in three variables: two rows of scales 1e4 apart (as rows on a
    position and on an acceleration) that nearly coincide leave a direction constrained by a
    singular value 1e-3 of A (7e-4 of its unit rows). H is -0.01 there and +1 on the free
    direction: convex on the null space. A penalty relative to the widest row gave that direction
    1e-6 of H's scale, took the model for indefinite and shifted it by 0.01 (on the grasp: 40,
    a proximal crawl at the iteration limit); unit rows give it 0.5."""
    import scipy.sparse as sps
    from stw_scipy.linear import SparseAlgebra
    from stw_tui.sos.sqp.curvature import convexify

    la = SparseAlgebra()
    e = 1e-3
    A = sps.csr_array([[1.0, 0.0, 0.0], [1e4 * (1.0 - e), 1e4 * e, 0.0]])   # null space: e₂ only
    H = sps.csr_array(np.diag([-0.01, -0.01, 1.0]))
    model, shift = convexify(la, H, A)
    assert shift == 0.0 and model is H
    # without the first row, a direction near e₁ is free where H is -0.01: that is the model's,
    # and it is shifted, just enough
    assert 0.01 / 10 ** (1 / 8) < convexify(la, H, A[[1]])[1] <= 0.01 * 10 ** (1 / 8)


CATCH = """
time 0 2 knots=20
dof cx, cy
constraint start: cx = 0, cy = 0, cx' = 0, cy' = 0 @ 0
constraint catch: cx = 3, cy = 1 @ 2
objective effort: cx'', cy''
"""


def test_a_limited_step_the_model_predicted_exactly_lifts_the_limit(monkeypatch):
    """A QP (linear constraints, quadratic objective) whose first step the limit cuts (the cat
    runs 3 m, the limit starts at 0.5): the model predicts the merit exactly along it (ratio 1 to
    rounding), so the limit goes to its ceiling and the next step is the QP's own, the solution
    at the second iteration, where doubling the limit took three."""
    from stw_tui.sos.sqp import solver

    fast = _solve(CATCH, "scipy", 10)
    monkeypatch.setattr(solver, "RATIO_EXACT", -1.0)   # doubling only
    slow = _solve(CATCH, "scipy", 10)
    assert [r.converged for r in fast.runs[-1].reports] == [False, True]
    assert len(slow.runs[-1].reports) == 3 and slow.runs[-1].converged
    assert fast.runs[-1].reports[0].step_length == 1.0
    # The Euler-Lagrange solution, which the cubic B-spline holds exactly: x'''' = 0 with x(0) =
    # x'(0) = 0, x(2) = 3 and the natural end x''(2) = 0 give x = 9/8 t^2 - 3/16 t^3, and y = x/3.
    # Both stop once the KKT residual is below tol_kkt (1e-6): within 1e-6 of it.
    t = np.linspace(0, 2, 101)
    exact = 9 / 8 * t ** 2 - 3 / 16 * t ** 3
    for session in (fast, slow):
        x, y = (session.scene.dofs[d].curve.evaluate(t) for d in ("cx", "cy"))
        np.testing.assert_allclose(x, exact, atol=1e-6)
        np.testing.assert_allclose(y, exact / 3, atol=1e-6)


def test_exact_steps_refused_in_a_row_wait_for_doubling_runs_of_gauss_newton_steps():
    from stw_tui.sos.sqp.solver import NEWTON_WAIT_MAX, _newton_backoff

    state = SolverState(s=np.zeros(1), lam_eq=np.zeros(0), lam_ge=np.zeros(0), working_set=np.zeros(0, bool))
    waits = []
    for _ in range(5):   # refused whenever tried: the first alone waits for nothing
        refusals, wait = _newton_backoff(state, True)
        waits.append(wait)
        state = replace(state, newton_refusals=refusals, newton_wait=wait)
    assert waits == [0, 1, 2, 4, min(8, NEWTON_WAIT_MAX)] and NEWTON_WAIT_MAX == 4
    # Gauss-Newton steps while waiting count the wait down and keep the refusals ...
    assert _newton_backoff(state, None) == (5, 3)
    # ... and an accepted exact step ends both.
    assert _newton_backoff(state, False) == (0, 0)


# basketball.stw as it was before `hold` attached the ball to the hand: the ball a DOF of its own,
# tracked by an objective while held (the lines the verb made then), on a massless base. It
# refuses runs of exact-Hessian steps, which the test below is about.
_MATCH = ("BX = player.tip.x, BY = player.tip.y, BZ = player.tip.z, "
          "BX' = player.tip.x', BY' = player.tip.y', BZ' = player.tip.z'")
BASKETBALL_TRACKED = f"""time 0 3 knots=48 samples=48
const g = 9.81
linkage player base=tx:PX,tz:PZ,ry:TURN
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
  WRIST    revolute a=0.15 mass=0.5
end
dof BX, BY, BZ
limit SHOULDER -2.6 3.2
limit ELBOW 0 2.5
limit WRIST -1.2 1.2
limit TURN -1.6 1.6
dof SHOULDER = -pi/2
dof PX = 0.8*min(max((t - 0.7)/0.8, 0), 1)
dof BX = 0.8*min(max((t - 0.5)/1.0, 0), 1)
dof BY = -0.8 + 2*sin(pi*min(max((t - 0.5)/1.0, 0), 1))
constraint start:  SHOULDER = -pi/2, ELBOW = 0, WRIST = 0, SHOULDER' = 0, ELBOW' = 0, WRIST' = 0 @ 0
constraint still0: PX = 0, PZ = 0, TURN = 0, PX' = 0, PZ' = 0, TURN' = 0 @ 0
objective B_held: player.tip.x - BX, player.tip.y - BY, player.tip.z - BZ on [0, 0.55] weight=1e4
constraint B_released: {_MATCH} @ 0.55
constraint B_flight: BX'' = 0, BY'' + g = 0, BZ'' = 0 on [0.55, 1.5]
constraint goal:   BX = 0.8, BY = 1.2, BZ = 0.5 @ 1
objective B_held2: player.tip.x - BX, player.tip.y - BY, player.tip.z - BZ on [1.5, 1.95] weight=1e5
constraint B_caught: {_MATCH} @ 1.5
constraint B_released2: {_MATCH} @ 1.95
constraint B_flight2: BX'' = 0, BY'' + g = 0, BZ'' = 0 on [1.95, 3.0]
constraint basket: BX = 2, BY = 1, BZ = 1 @ 3
constraint still3: PX' = 0, PZ' = 0, TURN' = 0 @ 3
objective effort:  tau_SHOULDER, tau_ELBOW, tau_WRIST, tau_PX, tau_PZ, tau_TURN
iterate 400
"""


def test_backing_off_refused_exact_steps_reaches_the_same_basketball_motion_with_fewer_refusals(monkeypatch):
    """BASKETBALL_TRACKED refuses some of its exact-Hessian steps, in runs: the backoff takes
    Gauss-Newton steps there instead of solving each refused QP first, so fewer exact steps are
    refused, and the solve ends at the same optimum. (How many linear iterations that saves turns
    on rounding: 942 to 501 when the backoff was made, 477 to 506 (a loss) on this machine's
    pinned kernels once more of basketball's working sets were factorized banded.)"""
    from stw_tui.sos.sqp import solver

    runs, refused, default = {}, {}, solver.NEWTON_WAIT_MAX
    text = BASKETBALL_TRACKED
    backoff_of = solver._newton_backoff
    for wait_max in (default, 0):   # 0: the exact step is tried at every step
        monkeypatch.setattr(solver, "NEWTON_WAIT_MAX", wait_max)
        refused[wait_max] = []
        monkeypatch.setattr(solver, "_newton_backoff", lambda st, exact_refused, out=refused[wait_max]: (
            out.append(bool(exact_refused)) or backoff_of(st, exact_refused)))
        session = Session()
        session.run_text(text)
        runs[wait_max] = session
    backoff, always = runs[default], runs[0]
    for session in (backoff, always):
        assert session.runs[-1].converged
    assert 0 < sum(refused[default]) < sum(refused[0]), {k: sum(v) for k, v in refused.items()}
    a, b = backoff.runs[-1].reports[-1].objective, always.runs[-1].reports[-1].objective
    assert abs(a - b) <= 1e-9 * abs(b), (a, b)
    t = np.linspace(backoff.scene.t0, backoff.scene.t1, 201)
    for name, dof in backoff.scene.dofs.items():
        np.testing.assert_allclose(dof.curve.evaluate(t), always.scene.dofs[name].curve.evaluate(t), atol=1e-4)


def _uniform_merit_weights(monkeypatch):
    """The ℓ1 merit as it was before rows were weighed by their own multipliers: every row
    weighs what the heaviest one does."""
    from stw_tui.sos.sqp.solver import SQPBackend

    per_row = SQPBackend._merit_weights

    def uniform(self, *args):
        w_eq, w_ge = per_row(self, *args)
        rho = max(float(w_eq.max(initial=0.0)), float(w_ge.max(initial=0.0)))
        return np.full_like(w_eq, rho), np.full_like(w_ge, rho)

    monkeypatch.setattr(SQPBackend, "_merit_weights", uniform)


def _acrobat_solves(knots: int = 1, solves: int = 4, prefix: str = "") -> Session:
    """acrobat.stw as these tests measured it (tests/data/acrobat_by_constraints.stw: its foot
    planted by constraints at instances), with ``knots`` x its knots and samples, up to its
    ``solves``-th iterate."""
    import re

    text = (Path(__file__).parent / "data" / "acrobat_by_constraints.stw").read_text()
    text = re.sub(r"(knots|samples)=(\d+)", lambda m: f"{m.group(1)}={int(m.group(2)) * knots}", text)
    lines = text.splitlines()
    iterates = [i for i, line in enumerate(lines) if line.startswith("iterate")]
    session = Session()
    session.run_text(prefix + "\n".join(lines[:iterates[solves - 1] + 1]) + "\n")
    return session


def test_rows_weighed_by_their_own_multipliers_reach_acrobats_optimum_in_fewer_iterations(monkeypatch):
    """Near a solution, a step along acrobat's curved constraints raises rows' violation by
    O(|d|²) (the Maratos effect); one merit weight for all rows, 1.5x the largest multiplier
    (1.7e3), priced rows whose multipliers are 1e-3 to 6e-2 at that, and refused such steps (19
    in the second solve's 34 iterations). Weighed by their own multipliers, the same solve takes
    20 iterations instead of 37 to a tight KKT tolerance (1e-9), and both reach one optimum."""
    tight = "set tol_kkt 1e-9\n"
    per_row = _acrobat_solves(prefix=tight)
    _uniform_merit_weights(monkeypatch)
    uniform = _acrobat_solves(prefix=tight)
    for session in (per_row, uniform):
        assert all(run.converged for run in session.runs), [run.status for run in session.runs]
    its = {name: [len(run.reports) for run in session.runs]
           for name, session in (("per_row", per_row), ("uniform", uniform))}
    assert its["per_row"][1] <= 0.75 * its["uniform"][1], its   # measured 20 and 37
    assert sum(its["per_row"]) < sum(its["uniform"]), its
    a, b = per_row.runs[-1].reports[-1].objective, uniform.runs[-1].reports[-1].objective
    assert abs(a - b) <= 1e-8 * abs(b), (a, b)                  # 29.265149: 1.5e-9 apart
    t = np.linspace(per_row.scene.t0, per_row.scene.t1, 381)
    for name, dof in per_row.scene.dofs.items():               # 6.6e-6 apart at most
        other = uniform.scene.dofs[name].curve.evaluate(t)
        np.testing.assert_allclose(dof.curve.evaluate(t), other, atol=1e-4)


def test_acrobat_with_twice_its_knots_converges_where_one_merit_weight_crawled(monkeypatch):
    """acrobat.stw with every knot and sample count doubled: its jumps (first solve) and flights
    (second) converge (28 and 13 iterations when measured). With one weight for every row, both
    reached their limit of 60 iterations, most steps near feasible refused and retried shorter."""
    refined = _acrobat_solves(knots=2, solves=2)
    assert [run.converged for run in refined.runs] == [True, True], [run.status for run in refined.runs]
    for run in refined.runs:
        assert run.reports[-1].max_violation <= 1e-8 and len(run.reports) < 60
    _uniform_merit_weights(monkeypatch)
    crawled = _acrobat_solves(knots=2, solves=1)
    assert not crawled.runs[0].converged and len(crawled.runs[0].reports) == 60


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_an_elastic_step_descends_its_rows_weighted_merit(la):
    """Rows an elastic step leaves unmet weigh its slack cost ρ in the merit, rows it meets their
    own multipliers (below ρ), and the step still descends that merit: its directional
    derivative Σ wᵢ(|cᵢ + aᵢd| - |cᵢ|) + gᵀd is at most -dᵀHd. Far from feasible, every row
    weighs ρ."""
    from types import SimpleNamespace

    import scipy.sparse as sps
    from stw_tui.sos.sqp.qp import solve_qp

    rho = 10.0
    H = np.diag([2.0, 2.0, 2.0])
    g = np.array([0.5, -1.0, 0.25])
    # d₀ = 1 and d₀ = 3 cannot both hold (the step meets the nearer one, the other keeps a
    # slack); d₁ = 0.5 can (met); d₂ >= 0.2 binds against g₂ > 0 (met).
    A_e = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    c_e = np.array([-1.0, -3.0, -0.5])
    A_i, c_i = np.array([[0, 0, 1.0]]), np.array([-0.2])
    qp = solve_qp(la, la.matrix(sps.csr_array(H)), la.vector(g), la.matrix(sps.csr_array(A_e)),
                  la.vector(c_e), la.matrix(sps.csr_array(A_i)), la.vector(c_i), elastic=rho)
    d = la.numpy(qp.d)
    lin_e, lin_i = c_e + A_e @ d, c_i + A_i @ d
    assert abs(lin_e[1]) > 1 and abs(lin_e[0]) < 1e-8                     # d₀ = 3 left unmet ...
    assert abs(lin_e[2]) < 1e-8 and lin_i[0] > -1e-8                      # ... the others met
    sub = SimpleNamespace(qp=qp, lam_eq=la.numpy(qp.y), lam_ge=-la.numpy(qp.z))
    ev = SimpleNamespace(c_eq=c_e, c_ge=c_i)
    lin = SimpleNamespace(eq_rows=np.arange(3), ge_rows=np.arange(1))
    backend = ScipyBackend()
    w_eq, w_ge = backend._merit_weights(la, ev, lin, sub, {"merit": 1.0}, far=False)
    np.testing.assert_allclose(w_eq[1], rho, rtol=1e-6)                 # the unmet row weighs ρ
    assert 1.0 <= w_eq[2] < rho and 1.0 <= w_ge[0] < rho                  # met ones their own
    assert np.all(w_eq >= np.abs(sub.lam_eq) - 1e-9) and np.all(w_ge >= np.abs(sub.lam_ge) - 1e-9)
    change = w_eq @ (np.abs(lin_e) - np.abs(c_e)) + w_ge @ (np.maximum(0, -lin_i) - np.maximum(0, -c_i))
    assert g @ d + change <= -d @ H @ d + 1e-6 * rho
    far = backend._merit_weights(la, ev, lin, sub, {"merit": 1.0}, far=True)
    assert all(np.all(w == rho) for w in far)


def test_a_step_after_one_that_passed_first_time_evaluates_its_trial_whole_and_reaches_the_same_iterates(
        monkeypatch):
    """After a step whose first attempt passed its first test, the next trial point is evaluated whole
    (values and Jacobians): when it passes too, that evaluation is the next iterate's, and the
    step costs one evaluation instead of a merit test and an evaluation. On this arm the iterates
    are bit for bit those of the solve that evaluates every accepted point again. (The merit
    test then reads the evaluation's objective, summed over all rows at once rather than group
    by group: elsewhere a ratio can differ in its last bits, and acrobat's motion by 4.7e-9.)"""
    import stw_tui.sos.sqp.solver as solver

    calls = []
    for name in ("evaluate", "merit_values"):
        made = getattr(WindowProblem, name)
        monkeypatch.setattr(WindowProblem, name,
                            lambda self, s, _made=made, _name=name: calls.append(_name) or _made(self, s))

    def solve():
        s = Session()
        s.run_text(ARM.replace("constraint reach: arm.tip.x <= 0.6 on [0, 2]\n", "") + "backend scipy")
        calls.clear()
        s.execute("iterate 40")
        reports = s.runs[-1].reports
        return s.scene.coefficient_vector().copy(), [r.objective for r in reports], list(calls)

    ahead, objectives, made = solve()
    # the first step tests its merit, then evaluates; later steps evaluate their trial only
    steps = len(objectives)
    assert made[:3] == ["evaluate", "merit_values", "evaluate"]
    assert steps >= 4 and made.count("evaluate") + made.count("merit_values") < 2 * steps

    # the same solve, never speculating: the next iterate is evaluated after its merit test
    step = solver.SQPBackend.step
    monkeypatch.setattr(solver.SQPBackend, "step", lambda self, problem, inner, k:
                        step(self, problem, replace(inner, speculate=False), k))
    again, objectives_again, made_again = solve()
    assert made_again.count("merit_values") >= steps
    assert objectives == objectives_again
    assert np.array_equal(ahead, again)


def test_the_newton_step_is_zero_along_control_points_nothing_reads():
    # min x0² + 2 x2² with x0 + x2 = 1 (x1 read by nothing): on the row's null space (1, 0, -1)
    # the Lagrangian gradient r = (1, 0, -3) gives the step -(r·n)/(nᵀHn) n = -4/6 (1, 0, -1);
    # along x1 the system was singular (KKT inf), and the step there is 0. A gradient along x1
    # (nothing curves or bounds it) has no Newton step: None.
    import scipy.sparse as sps
    from types import SimpleNamespace
    from stw_tui.sos.sqp.termination import newton_step

    ev = SimpleNamespace(lagrangian_hessian=lambda le, lg: sps.csr_array(np.diag([2.0, 0.0, 4.0])),
                         J_eq=sps.csr_array(np.array([[1.0, 0.0, 1.0]])), J_ge=sps.csr_array((0, 3)),
                         active_eq=np.array([True]), active_ge=np.zeros(0, bool))
    p = newton_step(ev, np.zeros(1), np.zeros(0), np.array([1.0, 0.0, -3.0]))
    np.testing.assert_allclose(p, [-2 / 3, 0.0, 2 / 3], atol=1e-9)   # to the (2,2) block ε = 1e-10
    assert newton_step(ev, np.zeros(1), np.zeros(0), np.array([1.0, 0.5, -3.0])) is None
