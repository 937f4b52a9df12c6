"""Every problem of the test catalogue on every installed backend (tests/catalogue.py)."""

import numpy as np
import pytest

import catalogue
from stw_tui.sos.backend import SolverState, create_backend, load_backend, run_iterations
from stw_tui.sos.window import WindowProblem


def test_the_catalogue_holds_every_bundled_session_and_the_analytic_problems():
    bundled = sorted(p.stem for p in catalogue.SESSIONS.glob("*.stw"))
    everyday = [p.name for p in catalogue.problems() if p.path is not None]
    assert sorted(everyday + list(catalogue.HEAVY)) == bundled and set(catalogue.HEAVY) <= set(bundled)
    assert set(catalogue.QUICK) <= set(bundled)
    assert all(p.known for p in catalogue.ANALYTIC.values())
    assert catalogue.installed_backends()[0] == "scipy"


def test_one_iteration_from_each_problem_on_each_backend(any_problem, any_backend):
    """From the scene before its first `iterate`, one iteration of any backend takes a finite
    step, and what it reports (objective, largest violation) is what the core's own evaluation of
    the window problem finds at the point it returns, and the objective what a fine trapezoid
    rule over the motion gives."""
    session = any_problem.setup()
    if not (session.scene.constraints or session.scene.objectives):
        pytest.skip("nothing to solve: the problem is a linkage alone")
    problem = WindowProblem(session.scene)
    options = dict(w.split("=") for w in catalogue.BACKEND_LINES[any_backend].split()[2:])
    backend = create_backend(load_backend(any_backend), options)
    result = run_iterations(backend, problem, SolverState.start(problem), 1, session.scene.settings)
    assert len(result.reports) == 1 and np.all(np.isfinite(result.state.s))
    assert result.state.s.shape == (problem.n_free,)
    report, ev = result.reports[0], problem.evaluate(result.state.s)
    assert report.objective == pytest.approx(ev.objective, rel=1e-9, abs=1e-12)
    assert report.max_violation == pytest.approx(ev.max_violation(), rel=1e-6, abs=1e-12)
    # (the problem's own rule is Gauss-Legendre, 4 points a knot span: on the wild motion of a
    # first step it differs from the fine trapezoid by up to 0.3% (luxo), 0.1% (basketball))
    assert report.objective == pytest.approx(_integrated(session.scene, problem, result.state.s), rel=1e-2)


def _integrated(scene, problem, s) -> float:
    """The objective of the motion with free control points ``s``: each term squared, weighed and
    integrated by the trapezoid rule on 1 ms-or-finer samples (Scene.evaluate per term), apart
    from the window problem's Gauss quadrature and its groups."""
    scene = scene.copy()
    full = scene.coefficient_vector()
    full[problem.free] = s
    scene.with_coefficients(full)
    total = 0.0
    for o in scene.objectives.values():
        a, b = o.interval or (scene.t0, scene.t1)
        t = np.linspace(a, b, max(2001, int((b - a) * 1000) + 1))
        total += o.weight * sum(np.trapezoid(scene.evaluate(e, t) ** 2, t) for e in o.exprs)
    return total
