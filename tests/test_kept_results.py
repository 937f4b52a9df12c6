"""Results kept between `iterate`s (expansions, free symbols, basis matrices, the backend scan)
are only reused where they cannot have changed."""

import numpy as np
import pytest

from stw_tui.session.session import Session
from stw_tui.sos import backend
from stw_tui.sos.spline import DofCurve


def test_redefining_a_subexpression_changes_what_the_next_iterate_solves():
    s = Session()
    s.run_text("time 0 1 knots=6\ndof x\nlet f = x\nconstraint c: f = 1 @ 0.5\n"
               "objective smooth: x''\niterate 10")
    assert s.scene.dofs["x"].curve.evaluate([0.5])[0] == pytest.approx(1.0, abs=1e-9)
    s.execute("let f = 2*x")                    # the same constraint text, a new expansion
    s.execute("iterate 10")
    assert s.scene.dofs["x"].curve.evaluate([0.5])[0] == pytest.approx(0.5, abs=1e-9)


def test_a_kept_basis_is_read_only_and_is_the_curve_s_derivative():
    rng = np.random.default_rng(3)
    curve = DofCurve.uniform(0.0, 2.0, 7).with_coef(rng.standard_normal(10))
    times = np.linspace(0.0, 2.0, 33)
    first, again = curve.basis(times, 2), curve.basis(times, 2)
    assert again is first
    with pytest.raises(ValueError):
        first.data[0] = 1.0
    # The same matrix on another curve with the same knots: the key is the knots, not the curve.
    other = curve.with_coef(rng.standard_normal(10))
    assert other.basis(times, 2) is first
    np.testing.assert_allclose(first @ other.coef, other.evaluate(times, 2), rtol=0, atol=1e-9)


def test_the_backend_scan_is_kept_and_an_unknown_name_scans_again(monkeypatch):
    calls = []
    real = backend.metadata.entry_points

    def counted(**kwargs):
        calls.append(kwargs)
        return real(**kwargs)

    monkeypatch.setattr(backend.metadata, "entry_points", counted)
    backend.forget_installed()
    names = backend.available_backends()
    backend.available_backends()
    assert "scipy" in names and len(calls) == 1
    with pytest.raises(Exception, match="no backend named 'nonesuch'"):
        backend.load_backend("nonesuch")
    assert len(calls) == 2                      # looked again before saying it is not there


def test_forgetting_empties_every_cache_a_window_build_fills():
    from stw_tui.sos import instances, kept, scene, spline, window
    from stw_tui.sym import compiler

    s = Session()
    s.run_text("time 0 1 knots=6\ndof x\nlet f = x^2\nconstraint c: f' = 1 on [0.2, 0.8]\n"
               "objective smooth: x''\niterate 2")
    window.WindowProblem(s.scene)
    assert scene._EXPANDED and spline._kept_basis.cache_info().currsize and window._BUILT
    assert compiler.free_symbols.cache_info().currsize and instances._KEPT
    kept.forget()
    assert not scene._EXPANDED and spline._kept_basis.cache_info().currsize == 0
    assert window._plan_set_of.cache_info().currsize == 0
    assert not compiler._CACHE
    assert compiler.free_symbols.cache_info().currsize == 0
    assert compiler._check_size.cache_info().currsize == 0
    assert instances._exact_degree.cache_info().currsize == 0
    assert not instances._KEPT and not window._BUILT


def _problem_data(problem) -> dict:
    """What a window problem holds and gives, comparable: its layout, its groups, P, and an
    evaluation at its start (values, Jacobians and the Hessian of a Lagrangian)."""
    from stw_tui.sos.window import WindowProblem

    assert isinstance(problem, WindowProblem)
    s = problem.initial()
    ev = problem.evaluate(s)
    lam_eq, lam_ge = np.linspace(1, 2, ev.c_eq.size), np.linspace(2, 3, ev.c_ge.size)
    groups = [(g.label, g.source, g.kind, g.term.expr, g.times.tobytes(), g.weights.tobytes(),
               np.asarray(g.params, float).tobytes(), g.slot_offset, g.row_offset, g.condition is None,
               g.linear)
              for g in problem.groups]
    dense = lambda m: np.asarray(m.toarray() if hasattr(m, "toarray") else m).tobytes()  # noqa: E731
    return {"free": problem.free.tobytes(), "coef0": problem.coef0.tobytes(), "reach": problem.reach,
            "rows": dict(problem.row_counts), "groups": groups, "P": dense(problem.P),
            "damping": problem.damping.tobytes(), "objective": ev.objective,
            "values": (ev.gradient.tobytes(), ev.c_eq.tobytes(), ev.c_ge.tobytes(),
                       ev.active_eq.tobytes(), ev.active_ge.tobytes()),
            "jacobians": (dense(ev.J_eq), dense(ev.J_ge)),
            "hessian": dense(ev.lagrangian_hessian(lam_eq, lam_ge))}


# Every command of the undo tests, and more that change what a window build reads.
from conftest import run_lines  # noqa: E402
from test_history import STEPS, TWO_D  # noqa: E402

CHANGES = STEPS + ["const m = 3", "set quadrature 3", "use w", "weight thrust 4", "delete band",
                   "instances band add 0.37", "constraint band: y >= -2 on [0, 2] samples=8",
                   "dof y lo=-4 hi=5", "let h = x - y", "objective small: maximize x on [0.5, 1.5] weight=0.1"]
# ... of which these change the problem itself (a kept one that missed them would differ)
STRUCTURAL = {"const m = 3", "set quadrature 3", "use w", "weight thrust 4", "delete band",
              "instances band add 0.37", "constraint band: y >= -2 on [0, 2] samples=8",
              "refine y [0.5, 1]", "set samples 20", "damp x 0.3", "window w dofs=y [0.5, 1.5]",
              "objective small: maximize x on [0.5, 1.5] weight=0.1"}


@pytest.mark.parametrize("command", CHANGES)
def test_a_window_problem_taken_from_the_last_build_is_what_a_new_build_makes(command):
    from stw_tui.sos.window import WindowProblem

    s = run_lines(Session(), TWO_D + "window w dofs=y [0.5, 1.5]\nuse all\n"
                                     "constraint band: y >= -1 on [0, 2]\nlet h = x + y\niterate 2\n")
    before = _problem_data(WindowProblem.of(s.scene))    # kept for this structure
    s.execute(command)
    after = _problem_data(WindowProblem.of(s.scene))
    assert after == _problem_data(WindowProblem(s.scene))
    if command in STRUCTURAL:
        assert {k for k in after if after[k] != before[k]} - {"coef0", "objective", "values", "hessian"}


def test_a_solve_that_moves_the_control_points_keeps_the_window_build():
    from stw_tui.sos.window import WindowProblem

    s = run_lines(Session(), TWO_D + "iterate 2\n")
    first = WindowProblem.of(s.scene)
    s.execute("iterate 3")
    again = WindowProblem.of(s.scene)
    assert again.P is first.P and again.groups is first.groups   # the same build, not a new one
    assert not np.array_equal(again.coef0, first.coef0)          # on the new control points
    assert _problem_data(again) == _problem_data(WindowProblem(s.scene))


def test_turning_an_objective_into_a_signed_one_is_a_new_structure():
    """The same expression, interval and weight, squared and then maximized: the kept build of
    the first must not serve the second (the structure key holds the objective's sense)."""
    from stw_tui.sos.window import WindowProblem

    s = run_lines(Session(), TWO_D + "objective small: x on [0.5, 1.5] weight=0.1\niterate 2\n")
    before = _problem_data(WindowProblem.of(s.scene))
    s.execute("objective small: maximize x on [0.5, 1.5] weight=0.1")
    after = _problem_data(WindowProblem.of(s.scene))
    assert after == _problem_data(WindowProblem(s.scene))
    assert after["groups"] != before["groups"] and after["objective"] != before["objective"]
