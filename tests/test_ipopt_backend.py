"""The ipopt backend (IPOPT through CasADi) reaches the SciPy backend's optima."""

import threading

import numpy as np
import pytest

casadi = pytest.importorskip("casadi")

import catalogue  # noqa: E402
from stw_tui.session.session import Session  # noqa: E402
from stw_tui.sos.backend import SolverState, load_backend, run_iterations  # noqa: E402
from stw_tui.sos.window import WindowProblem  # noqa: E402

IpoptBackend = catalogue.backend_package("stw_ipopt").IpoptBackend


def _coefficients(session):
    return session.scene.coefficient_vector()


@pytest.mark.parametrize("problem", catalogue.problems("particle_jet", "point_mass_2d"), ids=str)
def test_session_reaches_the_scipy_motion(registered, problem):
    text = problem.text
    ref, got = Session(), Session()
    ref.run_text(text)
    got.run_text("backend ipopt\n" + text)
    assert all(r.converged for r in ref.runs) and all(r.converged for r in got.runs)
    assert np.abs(_coefficients(got) - _coefficients(ref)).max() <= 1e-6


PARTICLE = catalogue.problem("analytic_particle").text + "backend ipopt\niterate 20\n"


def test_particle_optimum_is_the_cubic(registered):
    s = Session()
    s.run_text(PARTICLE)
    assert s.runs[-1].converged
    t = np.linspace(0, 1, 101)
    x = s.scene.dofs["x"].curve.evaluate(t)
    assert np.max(np.abs(x - (3 * t**2 - 2 * t**3))) < 1e-7
    assert s.runs[-1].reports[-1].objective == pytest.approx(12 + 9.81**2, rel=1e-7)


DOUBLE_INTEGRATOR = catalogue.problem("analytic_double_integrator").text + "{backend}iterate 100\n"


def test_double_integrator_matches_scipy(registered):
    ref, got = Session(), Session()
    ref.run_text(DOUBLE_INTEGRATOR.format(backend=""))
    got.run_text(DOUBLE_INTEGRATOR.format(backend="backend ipopt\n"))
    assert ref.runs[-1].converged and got.runs[-1].converged, got.runs[-1].status
    assert np.abs(_coefficients(got) - _coefficients(ref)).max() <= 1e-6
    x = got.scene.dofs["x"].curve.evaluate(np.linspace(0, 1, 241))
    assert x.max() <= 1 / 9 + 1e-8
    report = got.runs[-1].reports[-1]
    assert report.active > 0 and report.objective == pytest.approx(ref.runs[-1].reports[-1].objective,
                                                                   rel=1e-6)


def test_driver_reports_every_ipopt_iteration_and_multipliers(registered):
    session = catalogue.problem("point_mass_2d").setup()
    problem = WindowProblem(session.scene)
    start = SolverState.start(problem)
    result = run_iterations(load_backend("ipopt")(), problem, start, 500, session.scene.settings)
    assert result.converged and len(result.reports) >= 2
    assert [r.iteration for r in result.reports] == list(range(1, len(result.reports) + 1))
    assert "ipopt" in result.reports[0].ms and all(not r.converged for r in result.reports[:-1])
    # Intermediate iterates move: the first report's curve is not the final one.
    assert np.abs(result.reports[0].coefficients - result.reports[-1].coefficients).max() > 1e-6
    # Multipliers in stw's sign convention: binding inequalities have λ <= 0, none positive.
    assert result.state.lam_ge.max(initial=0.0) <= 1e-8 and result.state.lam_ge.min(initial=0.0) < 0
    ev = problem.evaluate(result.state.s)
    r = ev.gradient + ev.J_eq.T @ result.state.lam_eq + ev.J_ge.T @ result.state.lam_ge
    assert np.abs(r).max() <= 1e-5 * max(1.0, np.abs(ev.gradient).max())


def test_options_and_limited_memory(registered):
    with pytest.raises(Exception):
        IpoptBackend(hessian="newton")
    session = Session()
    session.run_text(PARTICLE.replace("backend ipopt", "backend ipopt hessian=limited_memory max_iter=200")
                     .replace("iterate 20", "iterate 300"))
    assert session.runs[-1].converged, session.runs[-1].status
    t = np.linspace(0, 1, 11)
    assert np.max(np.abs(session.scene.dofs["x"].curve.evaluate(t) - (3 * t**2 - 2 * t**3))) < 1e-4


def test_settings_the_chosen_backend_ignores_are_warned_about(registered):
    """IPOPT declares no damping: `damp` under it, and choosing it for a damped scene, say so;
    scipy honours damping and says nothing."""
    from stw_tui.sos.backend import Capability

    assert Capability.DAMPING not in IpoptBackend.capabilities
    s = Session()
    s.run_text("dof x, y lo=0\nconstraint c: x = 1 @ 0 weight=2\n")
    assert "warning" not in s.execute("damp x 0.2").message            # scipy: damping honoured
    switched = s.execute("backend ipopt").message
    assert switched.splitlines() == ["backend ipopt",
                                     "warning: backend ipopt does not support damping (x); the solve ignores it"]
    assert "does not support damping (x, y)" in s.execute("damp y 0.1").message
    assert s.execute("damp x 0").message.endswith("does not support damping (y); the solve ignores it")
    assert s.execute("backend scipy").message == "backend scipy"


def test_iterate_n_runs_n_ipopt_iterations_and_a_further_iterate_goes_on(registered):
    # IPOPT solves in one call; `iterate 3` hands it max_iter = 3, so three iterations are run
    # (not the whole solve with three of them shown), and the run ends at the iteration limit,
    # not as stalled. A further iterate restarts IPOPT from there and converges to the optimal
    # value of a single long run.
    text = ("time 0 1 knots=12\ndof x = 1.4 + 0.1*t\nconstraint c: sin(x) <= 0.5 on [0, 1]\n"
            "objective o: x''\nbackend ipopt\n")
    whole = Session()
    whole.run_text(text + "iterate 200\n")
    assert whole.runs[-1].converged and len(whole.runs[-1].reports) > 5
    s = Session()
    s.run_text(text + "iterate 3\n")
    first = s.runs[-1]
    assert len(first.reports) == 3 and first.status.name == "MAX_ITERATIONS", first.status
    assert "Maximum_Iterations_Exceeded" in first.reports[-1].message
    s.execute("iterate 200")
    assert s.runs[-1].converged     # the optimum is a family (any straight x below asin(0.5)): compare values
    assert s.runs[-1].reports[-1].objective == pytest.approx(whole.runs[-1].reports[-1].objective, abs=1e-8)


def test_a_stop_request_ends_ipopt_between_its_iterations(registered):
    # The TUI's stop flag rides on the report callback (on_report.cancelled); IPOPT, which runs
    # its whole solve inside one step, polls it in its iteration callback. Here the flag goes
    # up at IPOPT's 3rd iteration: the run stops there, with that iterate, instead of finishing.
    text = ("time 0 1 knots=12\ndof x = 1.4 + 0.1*t\nconstraint c: sin(x) <= 0.5 on [0, 1]\n"
            "objective o: x''\n")
    session = Session()
    session.run_text(text)
    problem = WindowProblem(session.scene)
    polls = []

    def on_report(report):
        return False                    # the flag is up: stop at the first boundary

    def ipopt_polls():      # IPOPT's own polls, not the driver's watch for a hung backend's
        if threading.current_thread().name.startswith("stw-backend"):
            polls.append(1)
        return len(polls) >= 3
    on_report.cancelled = ipopt_polls
    result = run_iterations(IpoptBackend(), problem, SolverState.start(problem), 200,
                            session.scene.settings, on_report)
    assert result.status.name == "STOPPED" and len(result.reports) == 1
    assert len(polls) == 3 and "User_Requested_Stop" in result.reports[0].message
    whole = run_iterations(IpoptBackend(), problem, SolverState.start(problem), 200, session.scene.settings)
    assert whole.converged and np.abs(result.state.s - whole.state.s).max() > 1e-6   # it did stop early


@pytest.mark.parametrize("name", ["arm_throw", "arm_overhand"])
def test_control_points_that_nothing_reads_leave_the_convergence_test_finite(registered, name):
    # Inside its hold the ball's curve is read nowhere (the hand is): arm_throw's 16 such control
    # points have no Hessian entry and no row, so the Newton system of the convergence test
    # (termination.newton_step, and this backend's dense copy) was singular, its KKT residual
    # inf, and IPOPT's optimum was reported as "no further progress". The step is zero along them.
    # IPOPT reaches a local optimum other than scipy's here; it passes the same test as any.
    s = Session()
    s.run_text("backend ipopt\n" + catalogue.problem(name).text)
    for run in s.runs:
        last = run.reports[-1]
        assert run.converged, last.message
        assert last.kkt_residual <= s.scene.settings["tol_kkt"]     # measured: 1e-15 to 4e-14
