"""The banded LU of KKT systems (backends/stw_scipy/banded.py) against SuperLU and dense LAPACK."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from stw_scipy.banded import BAND_MAX, BandedLU, BandPlan
from stw_scipy.linear import SparseAlgebra, kkt_matrix
from stw_scipy.ordering import PermutedLU, factorize


def _time_banded_kkt(rng, dofs: int, points: int, rows: int, shuffle: bool = True):
    """A KKT system shaped like a window problem's: ``dofs`` curves of ``points`` control points,
    each coupled with the next three of every curve (H), and ``rows`` constraint rows that each
    touch four consecutive control points of two curves; the unknowns in a shuffled order (RCM
    has to find the band)."""
    n = dofs * points
    index = np.arange(n).reshape(dofs, points)
    Hr, Hc = [], []
    for k in range(points):
        near = index[:, k:k + 4].ravel()
        for a in index[:, k]:
            Hr += [int(a)] * near.size
            Hc += near.tolist()
    H = sps.coo_array((rng.standard_normal(len(Hr)), (Hr, Hc)), shape=(n, n)).tocsr()
    H = sps.csr_array(H + H.T + 4.0 * sps.eye_array(n))
    Ar, Ac = [], []
    for r in range(rows):
        k = int(rng.integers(0, points - 3))
        for d in rng.choice(dofs, min(2, dofs), replace=False):
            Ar += [r] * 4
            Ac += index[d, k:k + 4].tolist()
    A = sps.coo_array((rng.standard_normal(len(Ar)), (Ar, Ac)), shape=(rows, n)).tocsr()
    A.sum_duplicates()
    if shuffle:
        p = rng.permutation(n)
        H, A = sps.csr_array(H[p][:, p]), sps.csr_array(A[:, p])
    return H, A


def test_banded_lu_solves_kkt_systems_as_superlu_does_to_rounding():
    """Indefinite KKT systems with the -1e-10 (2,2) block of the SQP's QPs: the banded LU's
    solution agrees with SuperLU's and with LAPACK's dense LU to rounding (relative 1e-9; these
    systems' condition numbers are 1e2-1e4), for a vector and for a matrix of right-hand sides."""
    rng = np.random.default_rng(3)
    for dofs, points, rows in ((1, 12, 4), (3, 20, 15), (4, 27, 30)):
        H, A = _time_banded_kkt(rng, dofs, points, rows)
        K = kkt_matrix(H, A, 1e-10)
        plan = BandPlan.of(K)
        assert plan is not None   # a band of a few spans of every curve: 5, 26 and 44 wide
        lu = plan.factorize(K)
        b = rng.standard_normal(K.shape[0])
        B = rng.standard_normal((K.shape[0], 3))
        dense = np.linalg.solve(K.toarray(), b)
        for got, want in ((lu.solve(b), spla.splu(K).solve(b)), (lu.solve(b), dense),
                          (lu.solve(B), np.linalg.solve(K.toarray(), B))):
            assert np.abs(got - want).max() <= 1e-9 * np.abs(want).max()
        assert np.abs(K @ lu.solve(b) - b).max() <= 1e-9 * np.abs(b).max()


def test_a_plan_is_made_once_per_structure_and_replays_from_values_alone():
    """The next K of a structure is factorized by the remembered plan (no new RCM), bit for bit as
    a plan made afresh would, also from its CSC values alone (the interior-point systems)."""
    rng = np.random.default_rng(4)
    H, A = _time_banded_kkt(rng, 3, 15, 10)
    plans: list = []
    for _ in range(5):
        H.data[:] = rng.standard_normal(H.nnz)
        A.data[:] = rng.standard_normal(A.nnz)
        K = kkt_matrix(sps.csr_array(H + H.T + 8.0 * sps.eye_array(H.shape[0])), A, 1e-10)
        b = rng.standard_normal(K.shape[0])
        lu = factorize(K, plans, band_max=BAND_MAX)
        assert isinstance(lu, BandedLU) and len(plans) == 1
        fresh = BandPlan.of(K)
        assert np.array_equal(lu.solve(b), fresh.factorize_values(K.data).solve(b))
        assert np.array_equal(lu.solve(b), plans[0].factorize_values(K.data).solve(b))


def test_wide_structures_stay_with_superlu_and_superlu_can_be_asked_for():
    """A structure wider than the limit (dense coupling) gets no plan and is factorized by
    SuperLU, as every KKT is when banding is off (band_max 0, the option factor=superlu)."""
    rng = np.random.default_rng(5)
    n, m = 70, 20
    H = sps.random_array((n, n), density=0.5, rng=rng, format="csr")
    K = kkt_matrix(sps.csr_array(H + H.T + n * sps.eye_array(n)),
                   sps.random_array((m, n), density=0.5, rng=rng, format="csr"), 1e-10)
    assert BandPlan.of(K) is None
    assert isinstance(factorize(K, [], band_max=BAND_MAX), PermutedLU)
    H, A = _time_banded_kkt(rng, 2, 10, 5)
    K = kkt_matrix(H, A, 1e-10)
    assert isinstance(factorize(K, [], band_max=BAND_MAX), BandedLU)
    assert isinstance(factorize(K, []), PermutedLU)
    assert SparseAlgebra(factor="superlu").band_max == 0 and SparseAlgebra().band_max == BAND_MAX


def test_an_exactly_singular_kkt_is_refused_as_superlu_refuses_it():
    """A zero pivot raises RuntimeError, which the KKT systems turn into SingularSystem (the QP then
    regularizes), as SuperLU's "Factor is exactly singular" does."""
    from stw_tui.sos.sqp.algebra import SingularSystem

    rng = np.random.default_rng(6)
    H, A = _time_banded_kkt(rng, 2, 10, 5, shuffle=False)
    keep = np.ones(H.shape[0])
    keep[3] = 0.0                       # an unknown that nothing touches: a zero column of K
    D = sps.diags_array(keep)
    H, A = sps.csr_array(D @ H @ D), sps.csr_array(A @ D)
    H.eliminate_zeros()
    A.eliminate_zeros()
    K = kkt_matrix(H, A, 1e-10)
    with pytest.raises(RuntimeError):
        spla.splu(K)
    with pytest.raises(RuntimeError):
        BandPlan.of(K).factorize(K)
    with pytest.raises(SingularSystem):
        SparseAlgebra().kkt(H, A, 1e-10, exact=True)


def test_the_scipy_backend_reaches_the_same_motion_with_every_factorization(monkeypatch):
    """A bundled session's first solve with each `factor`: sparse (banded LU where it can),
    superlu, dense, and auto (dense on this small window): the same iterations and control
    points within 1e-9 (the factorizations differ in rounding only), each by its own kind."""
    from pathlib import Path

    import stw_scipy.banded as banded
    import stw_scipy.dense as dense

    from stw_tui.session.bench import _fresh, split_at_first_iterate
    from stw_tui.session.session import Session

    text = (Path(__file__).parent.parent / "sessions" / "point_mass_2d.stw").read_text()
    pre, n = split_at_first_iterate(text)
    setup = Session()
    setup.run_text(pre)
    runs, made = {}, {"banded": 0, "dense": 0}
    banded_lu, dense_lu = banded.BandPlan.factorize_values, dense.DenseKKT.__init__

    def count(kind, fn):
        def counted(*args):
            made[kind] += 1
            return fn(*args)
        return counted
    monkeypatch.setattr(banded.BandPlan, "factorize_values", count("banded", banded_lu))
    monkeypatch.setattr(dense.DenseKKT, "__init__", count("dense", dense_lu))
    for factor in ("sparse", "superlu", "dense", "auto"):
        before = dict(made)
        session = _fresh(setup, f"scipy solver=direct factor={factor}")
        session.execute(f"iterate {n}")
        runs[factor] = (len(session.runs[-1].reports), session.scene.coefficient_vector().copy(),
                        {kind: made[kind] - before[kind] for kind in made})
    assert runs["sparse"][2]["banded"] > 0 and runs["sparse"][2]["dense"] == 0
    assert runs["superlu"][2] == {"banded": 0, "dense": 0}
    assert runs["dense"][2]["banded"] == 0 and runs["dense"][2]["dense"] > 0
    assert runs["auto"][2] == runs["dense"][2]   # 38 control points, 8 + 68 rows: a small window
    for factor in ("superlu", "dense", "auto"):
        assert runs[factor][0] == runs["sparse"][0]
        assert np.abs(runs[factor][1] - runs["sparse"][1]).max() <= 1e-9


def _pd_candidates(rng):
    """Symmetric matrices shaped like the curvature test's H + ρAᵀA (a band in a shuffled order):
    positive definite, indefinite (a negative shift), and one with a NaN."""
    H, A = _time_banded_kkt(rng, 4, 30, 60)
    base = sps.csr_array(H @ H.T + 1e4 * (A.T @ A))
    n = base.shape[0]
    lowest = float(np.linalg.eigvalsh(base.toarray()).min())
    shifts = (1e-3, -0.5 * lowest, -1.5 * lowest, -(lowest + 10.0))   # definite twice, then not
    return n, [sps.csr_array(base + s * sps.eye_array(n)) for s in shifts]


def test_banded_cholesky_tells_positive_definite_matrices_as_their_eigenvalues_do():
    """The curvature test's banded Cholesky (CholeskyBandPlan) against the smallest eigenvalue
    (numpy's dense eigvalsh, an independent computation), on matrices far from the boundary both
    ways; and against the algebra's own test of that size (LAPACK's dense Cholesky)."""
    from stw_scipy.banded import CholeskyBandPlan

    rng = np.random.default_rng(8)
    n, matrices = _pd_candidates(rng)
    superlu = SparseAlgebra(factor="superlu")
    answers = []
    for M in matrices:
        plan = CholeskyBandPlan.of(M)
        assert plan is not None and plan.fits(M)
        lowest = float(np.linalg.eigvalsh(M.toarray()).min())
        assert abs(lowest) > 1e-9 * float(np.abs(M.diagonal()).max())   # not within rounding of singular
        answers.append(plan.positive_definite(M))
        assert answers[-1] == (lowest > 0) == superlu.positive_definite(M)
    assert answers == [True, True, False, False]
    bad = matrices[0].copy()
    bad.data[5] = np.nan
    assert not CholeskyBandPlan.of(bad).positive_definite(bad)


def test_the_curvature_test_takes_the_banded_cholesky_above_the_dense_size(monkeypatch):
    """Above DENSE_TEST_MAX rows the default algebra tests by the banded Cholesky (a plan made once
    per structure), factor=superlu by SuperLU's LDLᵀ; both answer the same."""
    import stw_scipy.banded as banded
    import stw_scipy.linear as linear

    rng = np.random.default_rng(9)
    H, A = _time_banded_kkt(rng, 5, 70, 100)
    M = sps.csr_array(H @ H.T + 1e4 * (A.T @ A) + 1e-3 * sps.eye_array(H.shape[0]))
    assert M.shape[0] > linear.DENSE_TEST_MAX
    made = []
    of = banded.CholeskyBandPlan.of.__func__
    monkeypatch.setattr(banded.CholeskyBandPlan, "of",
                        classmethod(lambda cls, m, band_max=banded.CHOLESKY_BAND_MAX:
                                    made.append(1) or of(cls, m, band_max)))
    la = SparseAlgebra()
    assert la.positive_definite(M) and la.positive_definite(M)
    assert len(made) == 1 and la._cholesky_plans[0][1] is not None
    assert SparseAlgebra(factor="superlu").positive_definite(M) and len(made) == 1


def test_the_solver_runs_blas_on_one_thread_unless_told_otherwise():
    """Once a scipy algebra is made, numpy's and scipy's OpenBLAS use one thread; a thread count
    the user set in the environment is left as it is. (In child processes: the limit is global.)"""
    import subprocess
    import sys

    from conftest import ROOT

    probe = ("from threadpoolctl import threadpool_info\n"
             "from stw_scipy.sqp import ScipyBackend\n"
             "ScipyBackend(factor='sparse').algebra(None)\n"
             "print(sorted({i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'}))\n")
    env = {k: v for k, v in __import__("os").environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env["PYTHONPATH"] = f"{ROOT}:{ROOT / 'backends'}"
    run = lambda extra: subprocess.run([sys.executable, "-c", probe], env={**env, **extra},  # noqa: E731
                                       capture_output=True, text=True, timeout=120)
    assert run({}).stdout.strip() == "[1]", run({}).stderr
    assert run({"OPENBLAS_NUM_THREADS": "2"}).stdout.strip() == "[2]"


def test_an_iterate_takes_over_the_last_algebras_plans_and_solves_bit_for_bit(monkeypatch):
    """Each `iterate` makes a new algebra: it starts from the last one's plans (KKT layouts,
    orderings, banded plans), so a second solve of the same window works out no structure again,
    and reaches the control points of a solve that starts from none, bit for bit. An algebra with
    banding off never takes over banded plans."""
    from pathlib import Path

    import stw_scipy.banded as banded
    import stw_scipy.linear as linear

    from stw_tui.session.bench import _fresh, split_at_first_iterate
    from stw_tui.session.session import Session

    text = (Path(__file__).parent.parent / "sessions" / "arm_throw.stw").read_text()
    pre, n = split_at_first_iterate(text)
    setup = Session()
    setup.run_text(pre)
    made = []
    of, layout = banded.BandPlan.of, linear._Layout.__init__
    monkeypatch.setattr(banded.BandPlan, "of", classmethod(lambda cls, *a, **k: made.append("band") or of(*a, **k)))
    monkeypatch.setattr(linear._Layout, "__init__", lambda self, *a: made.append("layout") or layout(self, *a))

    def solve(options="") -> tuple[np.ndarray, int]:
        del made[:]
        session = _fresh(setup, f"scipy solver=direct {options}")
        session.execute(f"iterate {n}")
        return session.scene.coefficient_vector().copy(), len(made)

    monkeypatch.setattr(linear, "_LATEST_STRUCTURES", {})
    fresh, plans_fresh = solve()
    again, plans_again = solve()
    assert plans_fresh > 0 and plans_again < plans_fresh / 2
    assert np.array_equal(fresh, again)
    monkeypatch.setattr(linear, "_LATEST_STRUCTURES", {})
    assert np.array_equal(solve()[0], fresh)                      # from none again: the same
    superlu = linear.SparseAlgebra(factor="superlu")
    assert not any(isinstance(o, banded.BandPlan) for o in superlu._orderings)
    assert any(isinstance(o, banded.BandPlan) for o in linear.SparseAlgebra()._orderings)


def test_a_kept_ordering_factorizes_each_callers_values_when_two_threads_share_it():
    """A hung solve left running beside the next one may replay the same SuperLU ordering: each
    factorization is of its own caller's values (the ordering's scratch matrix is locked)."""
    import threading

    from stw_scipy.ordering import Ordering

    rng = np.random.default_rng(8)
    n = 400
    A = sps.random_array((n, n), density=0.02, rng=rng, format="csc") + 10.0 * sps.eye_array(n, format="csc")
    K = sps.csc_array(A)
    K.sort_indices()
    ordering = Ordering(K, spla.splu(K).perm_c, "COLAMD", {})
    wrong = []

    def work(seed: int) -> None:
        local = np.random.default_rng(seed)
        for _ in range(40):
            data = K.data * local.uniform(0.5, 1.5, K.nnz)
            Ki = sps.csc_array((data, K.indices, K.indptr), shape=K.shape)
            b = local.standard_normal(n)
            x = ordering.factorize_values(data).solve(b)
            wrong.append(np.abs(Ki @ x - b).max() > 1e-8 * np.abs(b).max())

    threads = [threading.Thread(target=work, args=(s,)) for s in (1, 2, 3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(wrong) == 120 and not any(wrong)


def test_orderings_kept_are_the_newest_and_older_ones_within_the_entry_budget(monkeypatch):
    """The newest ORDERINGS_KEPT structures stay whatever their size; older ones only while all
    kept hold at most ORDERINGS_ENTRIES stored entries (a large window's plans are not hoarded)."""
    import stw_scipy.ordering as ordering

    monkeypatch.setattr(ordering, "ORDERINGS_KEPT", 3)
    monkeypatch.setattr(ordering, "ORDERINGS_ENTRIES", 100)

    class Plan:
        def __init__(self, entries):
            self.key = ((1, 1), np.zeros(2), np.zeros(entries))

    kept: list = []
    small = [Plan(10) for _ in range(12)]
    for plan in small:
        ordering._remember(kept, plan)
    assert kept == small[::-1][:10]                 # 10 x 10 entries: the budget
    big = [Plan(60) for _ in range(4)]
    for plan in big:
        ordering._remember(kept, plan)
    assert kept == big[::-1][:3]                    # the newest 3 (180 entries) whatever their size


def _chain_with_a_spur(n: int = 60, reach: int = 3):
    """A band (each node coupled with the next ``reach``) whose least-degree node is a spur
    hung on its middle: scipy's RCM starts there and spreads both ways."""
    rows, cols = [], []
    for i in range(n):
        for j in range(i, min(n, i + reach + 1)):
            rows += [i, j]
            cols += [j, i]
    spur = n
    rows += [spur, n // 2, spur]
    cols += [n // 2, spur, spur]
    K = sps.csc_array((np.ones(len(rows)), (rows, cols)), shape=(n + 1, n + 1))
    K.sum_duplicates()
    return K


def test_rcm_from_the_far_end_when_scipys_start_doubles_the_band():
    """scipy's RCM from the spur gives about twice the band of one from the chain's end; past the
    limit the narrower order is kept, and the banded LU in it solves K as a dense solve does.
    Up to the limit scipy's order is kept exactly (the systems it suits stay bit for bit)."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    import stw_scipy.banded as banded

    pattern = _chain_with_a_spur()
    rng = np.random.default_rng(9)
    K = sps.csc_array(pattern.multiply(rng.standard_normal(pattern.shape)) + 20.0 * sps.eye_array(pattern.shape[0]))
    scipy_width = banded._rcm(K)[-1]
    assert scipy_width >= 6                                   # from the spur: both ways at once
    assert np.array_equal(banded._rcm(K, limit=scipy_width)[0], reverse_cuthill_mckee(K, symmetric_mode=True))
    narrow = banded._rcm(K, limit=scipy_width - 1)
    assert narrow[-1] <= 4                                    # the chain's own reach, plus the spur
    plan = banded.BandPlan.of(K, band_max=4)
    assert plan is not None and plan.width == narrow[-1]
    b = np.arange(K.shape[0], dtype=float)
    assert np.abs(plan.factorize(K).solve(b) - np.linalg.solve(K.toarray(), b)).max() <= 1e-9 * np.abs(b).max()


def test_every_kkt_system_of_luxo_is_factorized_banded(monkeypatch):
    """luxo.stw's working sets (the heel planted, the flight) made scipy's RCM start midway on 38
    of its 170 systems (bands 60-73, so SuperLU); from the far end they are bands of 31-33."""
    from pathlib import Path

    import stw_scipy.ordering as ordering

    from stw_tui.session.session import Session

    general = []
    splu = ordering.spla.splu
    monkeypatch.setattr(ordering.spla, "splu", lambda K, permc_spec="COLAMD", **kw: (
        general.append(permc_spec) if permc_spec == "COLAMD" else None) or splu(K, permc_spec=permc_spec, **kw))
    Session().run_text((Path(__file__).parent.parent / "sessions" / "luxo.stw").read_text())
    assert general == []
