"""The QP's active-set passes (qp._active_set): exact solutions from a nearby working set, and the
interior-point method whenever that guess cannot be trusted (nonconvex model, wholesale change)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sps

import catalogue

import stw_tui.sos.sqp.qp as qp_module
from stw_tui.sos.sqp.qp import solve_qp


def _box_qp(rng, n=30, me=3, convex=True):
    """min ½dᵀHd + gᵀd  s.t.  A_e d + c_e = 0,  -1 <= d <= 1 (rows d + 1 >= 0 and 1 - d >= 0)."""
    B = rng.standard_normal((n, n))
    H = B @ B.T / n + np.eye(n)
    if not convex:
        H -= 3.0 * np.eye(n)          # indefinite, also on the null space of the equality rows
    g = 3.0 * rng.standard_normal(n)  # large enough that many bounds bind
    Ae = rng.standard_normal((me, n))
    ce = 0.1 * rng.standard_normal(me)
    Ai = np.vstack([np.eye(n), -np.eye(n)])
    ci = np.ones(2 * n)
    return H, g, Ae, ce, Ai, ci


def _kkt_error(H, g, Ae, ce, Ai, ci, d, y, z):
    """The largest violation of the QP's KKT conditions (L = ½dᵀHd + gᵀd + yᵀ(A_e d + c_e) - zᵀ(A_i d + c_i))."""
    slack = Ai @ d + ci
    return max(np.abs(H @ d + g + Ae.T @ y - Ai.T @ z).max(), np.abs(Ae @ d + ce).max(),
               max(0.0, -slack.min()), max(0.0, -z.min()), np.abs(z * slack).max())


def _solve(la, parts, working, convex=False):
    H, g, Ae, ce, Ai, ci = parts
    return solve_qp(la, la.matrix(sps.csr_array(H)), la.vector(g), la.matrix(sps.csr_array(Ae)),
                    la.vector(ce), la.matrix(sps.csr_array(Ai)), la.vector(ci),
                    working=None if working is None else la.vector(working.astype(float)) > 0.5,
                    convex=convex)


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_a_nearby_working_set_is_corrected_by_active_set_passes_to_the_exact_solution(la):
    rng = np.random.default_rng(3)
    parts = _box_qp(rng)
    reference = _solve(la, parts, None)                      # the interior-point method (and polish)
    d_ref = la.numpy(reference.d)
    binding = la.numpy(reference.z) > 0
    assert 10 <= binding.sum() <= 50                         # a QP where the set matters
    # The step before bound a few rows fewer and one more: three rows to correct.
    guess = binding.copy()
    guess[np.flatnonzero(binding)[:2]] = False
    guess[np.flatnonzero(~binding)[0]] = True
    qp = _solve(la, parts, guess)
    assert qp.ipm_iterations == 0                            # settled by the passes alone ...
    assert 2 <= qp.linear_iterations <= 5                    # ... in a few factorizations
    d, y, z = la.numpy(qp.d), la.numpy(qp.y), la.numpy(qp.z)
    # An independent check: the KKT conditions of the convex QP (so its unique minimizer) hold
    # up to the proximal regularization ε = 1e-10 times the multipliers.
    assert _kkt_error(*parts, d, y, z) <= 1e-8
    np.testing.assert_allclose(d, d_ref, atol=1e-8)


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_a_model_not_convex_on_the_equality_rows_leaves_the_set_to_the_interior_point_method(la):
    # min ½(d₀² - d₁² + d₂²) - 0.5 d₀ + 0.1 d₁  s.t.  d₂ = 0.2,  -1 <= d₀, d₁ <= 1. Curved down along
    # d₁, so its minimizers sit on d₁'s bounds (d₁ = -1 is the best). From the guess "d₀ >= -1
    # binds", the first pass drops that row (multiplier -1.5) and the second would end at the
    # stationary point d₁ = 0.1, a maximum along d₁, which meets every KKT condition but the
    # second-order one (basketball.stw: QP objective -0.9 against the interior point's -13.6).
    H = np.diag([1.0, -1.0, 1.0])
    g = np.array([-0.5, 0.1, 0.0])
    Ae, ce = np.array([[0.0, 0.0, 1.0]]), np.array([-0.2])
    Ai = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    ci = np.ones(4)
    qp = _solve(la, (H, g, Ae, ce, Ai, ci), np.array([True, False, False, False]))
    d = la.numpy(qp.d)
    assert qp.ipm_iterations > 0
    assert abs(d[1]) == pytest.approx(1.0, abs=1e-9)          # on a bound, not at the maximum 0.1
    assert d[0] == pytest.approx(0.5, abs=1e-9) and d[2] == pytest.approx(0.2, abs=1e-9)


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_a_guess_that_changes_wholesale_is_left_to_the_interior_point_method(la):
    # An empty working set where many rows bind: the first pass would add more rows than the guess
    # holds (the first steps of a solve, far from the solution), so no passes are spent on it.
    rng = np.random.default_rng(3)
    parts = _box_qp(rng)
    qp = _solve(la, parts, np.zeros(parts[4].shape[0], bool))
    assert qp.ipm_iterations > 0
    d, y, z = la.numpy(qp.d), la.numpy(qp.y), la.numpy(qp.z)
    assert _kkt_error(*parts, d, y, z) <= 1e-8


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_a_model_known_positive_definite_skips_the_convexity_test_and_nothing_else(la, monkeypatch):
    # Gauss-Newton models plus a positive diagonal are positive definite by construction: the
    # solver says so (convex=True) and the passes spend no factorization on testing it. The
    # solution is the one the test would have let through, to the last bit.
    rng = np.random.default_rng(3)
    parts = _box_qp(rng)
    binding = la.numpy(_solve(la, parts, None).z) > 0
    guess = binding.copy()
    guess[np.flatnonzero(binding)[:2]] = False
    guess[np.flatnonzero(~binding)[0]] = True
    tested = _solve(la, parts, guess)
    calls = []
    monkeypatch.setattr(qp_module, "convex_on", lambda *a: calls.append(a) or True)
    trusted = _solve(la, parts, guess, convex=True)
    assert calls == []
    assert trusted.ipm_iterations == tested.ipm_iterations == 0
    assert trusted.linear_iterations == tested.linear_iterations
    for a, b in ((trusted.d, tested.d), (trusted.y, tested.y), (trusted.z, tested.z)):
        assert np.array_equal(la.numpy(a), la.numpy(b))
    # and without the flag the test is made (the nonconvex case above depends on it)
    _solve(la, parts, guess)
    assert len(calls) == 1


def test_a_refused_step_retries_from_the_rows_that_bound_in_the_refused_attempt(monkeypatch):
    # A refused step is tried again with a heavier proximal term: with the same model, only that
    # term changes, so the rows that bound in the refused attempt are a closer guess than the last
    # step's. In luxo, a retry whose refused attempt needed the interior-point method (9
    # iterations) then settles by active-set passes alone. A retry with another model (Gauss-Newton
    # then exact) starts from the last step's rows, as the first attempt did.
    import stw_tui.sos.sqp.solver as solver
    from conftest import SESSIONS
    from stw_tui.session.session import Session

    steps: list[list] = []
    step, subproblem = solver.SQPBackend.step, solver.SQPBackend._subproblem

    def counted_step(self, problem, inner, k):
        steps.append([])
        return step(self, problem, inner, k)

    def recorded(self, la, H, ev, lin, *args, **kwargs):
        sub, rho = subproblem(self, la, H, ev, lin, *args, **kwargs)
        if sub is not None and sub.qp.elastic is None and lin.ge_rows.size:
            steps[-1].append((la.numpy(lin.working).copy(), sub.working[lin.ge_rows], sub.qp.ipm_iterations))
        return sub, rho

    monkeypatch.setattr(solver.SQPBackend, "step", counted_step)
    monkeypatch.setattr(solver.SQPBackend, "_subproblem", recorded)
    session = Session()
    session.run_file(SESSIONS / "luxo.stw")
    assert all(run.converged for run in session.runs)
    guided = []
    for attempts in steps:
        first_guess = attempts[0][0] if attempts else None
        for (_, bound, ipm), (guess, _, ipm_after) in zip(attempts, attempts[1:]):
            from_refused = np.array_equal(guess, bound)
            assert from_refused or np.array_equal(guess, first_guess)
            if from_refused and not np.array_equal(bound, first_guess):
                guided.append((ipm, ipm_after))
    assert guided                                             # retries started from the refused rows ...
    assert any(ipm > 0 and ipm_after == 0 for ipm, ipm_after in guided)   # ... and settled at once


@pytest.mark.parametrize("la", catalogue.linear_algebras(), ids=lambda la: type(la).__name__)
def test_the_interior_point_method_crosses_over_to_its_settled_rows_before_it_converges(la, monkeypatch):
    # Its binding rows settle iterations before the residuals reach IPM_TOL; the exact solution on
    # them (what solve_qp makes of the converged iterate) ends it then, and is the same solution.
    parts = _box_qp(np.random.default_rng(5))
    crossed = _solve(la, parts, None)
    monkeypatch.setattr(qp_module, "CROSSOVER_ERROR", -1.0)   # never: the method runs to IPM_TOL
    converged = _solve(la, parts, None)
    assert crossed.ipm_iterations < converged.ipm_iterations
    d, y, z = la.numpy(crossed.d), la.numpy(crossed.y), la.numpy(crossed.z)
    assert _kkt_error(*parts, d, y, z) <= 1e-8               # independently: the convex QP's minimizer
    np.testing.assert_allclose(d, la.numpy(converged.d), atol=1e-12)
    np.testing.assert_allclose(z, la.numpy(converged.z), atol=1e-9)


def test_an_early_set_that_is_not_the_solution_lets_the_interior_point_method_go_on(monkeypatch):
    # Crossing over as soon as the residuals allow (before the rows settle) tries sets that fail
    # the KKT test; each is tried once, and the method goes on to the same solution.
    la = catalogue.linear_algebras()[0]
    parts = _box_qp(np.random.default_rng(0))                # (a seed where an early set fails)
    reference = _solve(la, parts, None)
    monkeypatch.setattr(qp_module, "CROSSOVER_ERROR", 1e3)
    tried = []
    on_set = qp_module._on_working_set

    def recorded(*args):
        result = on_set(*args)
        tried.append((la.numpy(args[9]).tobytes(), result is not None))   # (la, H, g, Ae, ce, Ai, ci, y0, z0, binding, ...)
        return result

    monkeypatch.setattr(qp_module, "_on_working_set", recorded)
    early = _solve(la, parts, None)
    assert any(not ok for _, ok in tried) and tried[-1][1]    # some failed, the last one held
    assert len({key for key, _ in tried}) == len(tried)       # no set solved twice
    np.testing.assert_allclose(la.numpy(early.d), la.numpy(reference.d), atol=1e-10)
