"""The ipopt backend's native path (issue 51, item 3): the window problem as CasADi expressions,
evaluated by CasADi with no stw evaluation per iteration, reaching the optima the SciPy backend
and a hand-written CasADi problem reach."""

import shutil

import numpy as np
import pytest
import sympy as sp

casadi = pytest.importorskip("casadi")

import catalogue  # noqa: E402
import ipopt_native  # noqa: E402
from stw_tui.session.session import Session  # noqa: E402
from stw_tui.sos.backend import SolverState, run_iterations  # noqa: E402
from stw_tui.sos.window import WindowProblem  # noqa: E402
from stw_tui.sym.compiler import compile_term  # noqa: E402
from stw_tui.sym.symbols import dof_symbol, named_symbol  # noqa: E402

ipopt = catalogue.backend_package("stw_ipopt")
backend_module = catalogue.backend_package("stw_ipopt.backend")
lowering = catalogue.backend_package("stw_ipopt.lowering")


def _counting(monkeypatch):
    """Count the window problem's Python evaluations (its values and derivatives)."""
    calls = {"evaluate": 0, "merit_values": 0}
    for name in calls:
        original = getattr(WindowProblem, name)

        def counted(self, *args, _original=original, _name=name, **kwargs):
            calls[_name] += 1
            return _original(self, *args, **kwargs)
        monkeypatch.setattr(WindowProblem, name, counted)
    return calls


def _solve(problem, settings, **options):
    return run_iterations(ipopt.IpoptBackend(**options), problem, SolverState.start(problem), 500, settings)


def test_native_path_evaluates_nothing_of_stw_per_iteration(monkeypatch):
    session, problem = ipopt_native._stw_problem(ipopt_native.PENDULUM.format(spans=20))
    calls = _counting(monkeypatch)
    result = _solve(problem, session.scene.settings)
    assert result.converged and len(result.reports) >= 5
    assert "native CasADi" in result.reports[-1].message
    # one evaluation for stw's own convergence test on the final point, whatever the iterations
    assert calls == {"evaluate": 1, "merit_values": 0}
    calls.update(evaluate=0, merit_values=0)
    through_stw = _solve(problem, session.scene.settings, evaluation="callback")
    assert "stw evaluations" in through_stw.reports[-1].message
    assert calls["evaluate"] > len(through_stw.reports)          # IPOPT called stw at every point
    assert through_stw.reports[-1].objective == pytest.approx(result.reports[-1].objective, rel=1e-10)


def test_a_kept_solver_serves_the_next_iterate(monkeypatch):
    session, problem = ipopt_native._stw_problem(ipopt_native.PENDULUM.format(spans=20))
    ipopt.backend.forget_solvers()
    first = _solve(problem, session.scene.settings)
    again = _solve(problem, session.scene.settings)
    assert "build" in first.reports[0].ms and "build" not in again.reports[0].ms
    assert np.array_equal(first.state.s, again.state.s)


@pytest.mark.parametrize("spans", [20, 80])
def test_pendulum_reaches_the_hand_written_casadi_optimum(spans):
    session, problem = ipopt_native._stw_problem(ipopt_native.PENDULUM.format(spans=spans))
    result = _solve(problem, session.scene.settings)
    solver, lbg, ubg = ipopt_native.native_pendulum(spans, int(session.scene.settings["quadrature"]))
    sol = solver(x0=problem.initial(), lbg=lbg, ubg=ubg)
    assert result.converged and solver.stats()["success"]
    assert result.reports[-1].objective == pytest.approx(float(sol["f"]), rel=1e-9)
    assert np.abs(result.state.s - np.asarray(sol["x"]).ravel()).max() <= 1e-6
    # the same IPOPT on the same problem takes the same path
    assert len(result.reports) == solver.stats()["iter_count"]


CONDITIONAL = """time 0 1 knots=12
dof x = 1.4 + 0.1*t
dof y = 0.2
constraint c: sin(x) <= 0.5 on [0, 1]
constraint near: y >= 0.1 + x/10 on [0, 1] when t > 0.5 and x > -5
constraint ends: y = 0.2, x = 0.25 @ 1
objective o: x'', y'', abs(y + 2) - 2*sign(x + 4), max(x, -3) + min(y, 4)
"""
HELD = """time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
end
dof BX, BY
dof SHOULDER = -pi/2
constraint hang: SHOULDER = -pi/2, ELBOW = 0, SHOULDER' = 0, ELBOW' = 0 @ 0
hold B at arm.tip on [0, 0.5] mass=0.2
ballistic B on [0.5, 1]
constraint goal: BX = 0.6, BY = 0 @ 1
objective effort: tau_SHOULDER, tau_ELBOW
"""
FUNCTIONS = """time 0 1 knots=10
dof x, y = 0.5
constraint start: x = 0, y = 0.5 @ 0
constraint end: x = 1, y = 1 @ 1
objective o: x'', y'', atan2(y + 2, x + 3) - sqrt(1 + x^2) + exp(-y) * cosh(x)
"""


@pytest.mark.parametrize("name, text", [
    ("particle_jet", catalogue.problem("particle_jet").before_first_iterate()),
    ("point_mass_2d", catalogue.problem("point_mass_2d").before_first_iterate()),
    ("double_integrator", catalogue.problem("analytic_double_integrator").text),
    ("landing", catalogue.problem("analytic_landing").text),
    ("conditional", CONDITIONAL),
    ("functions", FUNCTIONS),
])
def test_native_optimum_is_the_scipy_backends(registered, name, text):
    ref, got = Session(), Session()
    ref.run_text(text + "iterate 200\n")
    got.run_text("backend ipopt\n" + text + "iterate 500\n")
    assert ref.runs[-1].converged and got.runs[-1].converged, got.runs[-1].status
    assert "native CasADi" in got.runs[-1].reports[-1].message
    objective = ref.runs[-1].reports[-1].objective
    assert got.runs[-1].reports[-1].objective == pytest.approx(objective, rel=1e-6, abs=1e-9)


def test_a_held_object_gives_the_optimum_of_stws_evaluations(registered):
    """A hold makes the arm's torques and the ball's coordinates Piecewise in time: lowered,
    IPOPT takes the same path to the same point as through stw's evaluations. (Not compared
    with scipy: IPOPT stops at another local optimum, 3.10 against 2.29, where stw's own
    convergence test finds no Newton step.)"""
    found = {}
    for evaluation in ("native", "callback"):
        session = Session()
        session.run_text(f"backend ipopt evaluation={evaluation}\n" + HELD + "iterate 500\n")
        report = session.runs[-1].reports[-1]
        assert "Solve_Succeeded" in report.message and report.max_violation <= 1e-9
        found[evaluation] = (report.objective, session.scene.coefficient_vector())
    assert found["native"][0] == pytest.approx(found["callback"][0], rel=1e-9)
    assert np.abs(found["native"][1] - found["callback"][1]).max() <= 1e-6


X, Y, T = dof_symbol("x"), dof_symbol("y"), named_symbol("t")
K = named_symbol("k")


@pytest.mark.parametrize("expr", [
    sp.Abs(X - 0.5) * sp.sign(Y) + sp.Max(X, Y, 0.2) - sp.Min(X, 2 * Y),
    sp.atan2(Y, X) + sp.sqrt(1 + X**2) + X**-2 + sp.Rational(3, 2) ** X + K * sp.exp(-X) * sp.log(2 + Y),
    sp.Piecewise((X**2, T < 0.5), (K * Y, T < 0.8), (X + Y, True)) + sp.tanh(X) * sp.cosh(Y),
    sp.Piecewise((sp.sin(X), sp.And(X > 0, sp.Not(Y > 1))), (sp.cos(Y), sp.Or(Y < -1, sp.Eq(X, 0))), (X - Y, True)),
    sp.sign(sp.log(X)) + sp.asin(Y / 4) + sp.acos(X / 4) + sp.atan(X) + sp.tan(Y / 3) + sp.pi * sp.E,
])
def test_lowering_computes_what_the_compiled_term_computes(expr):
    term = compile_term(expr, {"x", "y"}, {"k"})
    f = lowering.term_function(term)
    rng = np.random.default_rng(3)
    n = 200
    values = np.column_stack([rng.uniform(-2, 2, n) for _ in term.variables])
    values[:10] = 0.0                                 # the kinks and branch points themselves
    times = rng.uniform(0, 1, n)
    params = np.array([1.7] * len(term.parameters))
    want = term.value(values, times, params)
    got = np.asarray(f.map(n)(values.T, times[None, :], np.repeat(params[:, None], n, 1))).ravel()
    both_nan = np.isnan(want) & np.isnan(got)
    assert np.all(both_nan | np.isclose(got, want, rtol=1e-12, atol=1e-12))
    # ... and the same first derivatives (abs at 0: 1, as symengine's Piecewise has it)
    full = term.full(values, times, params)[1]
    x = casadi.SX.sym("x", term.k)
    grad = casadi.Function("g", [x], [casadi.gradient(f(x, 0.3, params), x)])
    at = values[:20]
    mine = np.asarray(grad.map(20)(at.T)).T
    theirs = term.full(at, np.full(20, 0.3), params)[1]
    ok = (np.isnan(mine) & np.isnan(theirs)) | np.isclose(mine, theirs, rtol=1e-10, atol=1e-10)
    assert ok.all() and full.shape == (n, term.k)


def test_a_term_the_lowering_refuses_is_solved_through_stw(registered, monkeypatch):
    monkeypatch.delitem(lowering._UNARY, sp.sin)
    ipopt.backend.forget_solvers()          # no solver nor local derivatives kept, built with sin
    got = Session()
    got.run_text("backend ipopt\n" + ipopt_native.PENDULUM.format(spans=20) + "iterate 100\n")
    assert got.runs[-1].converged
    message = got.runs[-1].reports[-1].message
    assert "stw evaluations" in message and "does not know 'sin'" in message
    assert got.runs[-1].reports[-1].objective == pytest.approx(68.1321319590, rel=1e-9)


@pytest.mark.parametrize("graph", ["SX", "MX"])
@pytest.mark.parametrize("text", [HELD, CONDITIONAL, catalogue.problem("cat_mouse").before_first_iterate()],
                         ids=["held", "conditional", "cat_mouse"])
def test_native_derivatives_are_the_window_problems(text, graph):
    """The chain-rule gradient, Jacobian and Lagrangian Hessian assembled in CasADi equal stw's
    own (WindowProblem.evaluate, lagrangian_hessian) at a perturbed point, random multipliers
    and objective factor σ, in either graph."""
    import scipy.sparse as sps

    session = Session()
    session.run_text(text)
    problem = WindowProblem(session.scene)
    rng = np.random.default_rng(7)
    s = problem.initial() + 0.01 * rng.standard_normal(problem.n_free)
    ev = problem.evaluate(s)
    eq, ge = np.flatnonzero(ev.active_eq), np.flatnonzero(ev.active_ge)
    lam_eq, lam_ge = np.zeros(ev.c_eq.size), np.zeros(ev.c_ge.size)
    lam_eq[eq], lam_ge[ge] = rng.standard_normal(eq.size), -rng.random(ge.size)
    sigma = 0.7
    want_H = (ev.lagrangian_hessian(lam_eq, lam_ge)
              + (sigma - 1) * ev.lagrangian_hessian(0 * lam_eq, 0 * lam_ge)).toarray()
    nlp = ipopt.native.NativeNLP(problem, eq, ge, graph)
    assert nlp.graph == graph
    F = casadi.Function("F", [nlp.x, nlp.p, nlp.lam_f, nlp.lam_g],
                        [nlp.f, nlp.g, nlp.grad_f, nlp.jac_g, nlp.hess_lag])
    f, g, grad, J, H = F(s, ipopt.native.fixed_slot_values(problem), sigma, np.r_[lam_eq[eq], lam_ge[ge]])
    H = np.array(casadi.DM(H))
    assert np.allclose(H, np.triu(H))                       # IPOPT takes the upper triangle
    H = H + np.triu(H, 1).T
    scale = max(1.0, np.abs(want_H).max())
    assert float(f) == pytest.approx(ev.objective, rel=1e-12)
    assert np.allclose(np.asarray(g).ravel(), np.r_[ev.c_eq[eq], ev.c_ge[ge]], atol=1e-12)
    assert np.allclose(np.asarray(grad).ravel(), ev.gradient, atol=1e-10 * max(1.0, np.abs(ev.gradient).max()))
    want_J = sps.vstack([ev.J_eq[eq], ev.J_ge[ge]]).toarray()
    assert np.allclose(np.array(casadi.DM(J)), want_J, atol=1e-12)
    assert np.abs(H - want_H).max() <= 1e-12 * scale


@pytest.mark.skipif(shutil.which("cc") is None, reason="jit needs a C compiler")
def test_jit_compiles_the_same_problem():
    session, problem = ipopt_native._stw_problem(ipopt_native.PENDULUM.format(spans=20))
    vm = _solve(problem, session.scene.settings)
    compiled = _solve(problem, session.scene.settings, jit=True)
    assert compiled.converged and "jit failed" not in compiled.reports[-1].message
    assert len(compiled.reports) == len(vm.reports)
    assert np.abs(compiled.state.s - vm.state.s).max() <= 1e-9


def test_a_failed_jit_falls_back_to_the_virtual_machine(monkeypatch):
    monkeypatch.setenv("PATH", "/nonexistent")          # no cc to be found
    session, problem = ipopt_native._stw_problem(ipopt_native.PENDULUM.format(spans=20))
    ipopt.backend.forget_solvers()
    result = _solve(problem, session.scene.settings, jit=True)
    assert result.converged and "jit failed" in result.reports[-1].message


def test_auto_takes_stws_evaluations_where_casadis_would_be_slower(monkeypatch):
    session, problem = ipopt_native._stw_problem(ipopt_native.PENDULUM.format(spans=20))
    ipopt.backend.forget_solvers()
    assert ipopt.native.instructions(problem) <= ipopt.backend.NATIVE_INSTRUCTIONS
    monkeypatch.setattr(ipopt.backend, "NATIVE_INSTRUCTIONS", 0)
    auto = _solve(problem, session.scene.settings)
    assert "stw evaluations" in auto.reports[-1].message
    forced = _solve(problem, session.scene.settings, evaluation="native")
    assert "native CasADi" in forced.reports[-1].message
    assert forced.reports[-1].objective == pytest.approx(auto.reports[-1].objective, rel=1e-10)
