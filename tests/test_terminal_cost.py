"""A terminal (Mayer) cost, `objective NAME: EXPR @ T`, against the calculus of variations."""

import numpy as np
import pytest

from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError

BASE = """time 0 1 knots=8
dof y
constraint rest: y = 0, y' = 0 @ 0
objective fuel: y''
"""


@pytest.mark.parametrize("weight", [1.0, 100.0])
def test_a_terminal_cost_meets_the_euler_lagrange_optimum(weight):
    # min ∫0^1 y''^2 + W (y(1) - 2)^2 with y(0) = y'(0) = 0: y'''' = 0, so y = a t^2 + b t^3; the
    # free end gives y''(1) = 0 (a = -3b) and y'''(1) = W (y(1) - 2), so b = -W/(3 + W):
    # y(1) = 2W/(3 + W) and the objective 12 b^2 + W (y(1) - 2)^2. A cubic: the spline holds it.
    # (solved to tol_kkt 1e-12: the default 1e-6 stops within 2e-7 of this optimum)
    s = run_lines(Session(), BASE + f"objective high: y - 2 @ 1 weight={weight!r}\nset tol_kkt 1e-12\niterate 20\n")
    assert s.runs[-1].converged
    b = -weight / (3 + weight)
    end = 2 * weight / (3 + weight)
    assert s.scene.dofs["y"].curve.evaluate([1.0])[0] == pytest.approx(end, abs=1e-9)
    assert s.runs[-1].reports[-1].objective == pytest.approx(12 * b * b + weight * (end - 2) ** 2, rel=1e-9)
    t = np.linspace(0, 1, 11)
    assert np.allclose(s.scene.dofs["y"].curve.evaluate(t), -3 * b * t ** 2 + b * t ** 3, atol=1e-9)


def test_a_terminal_cost_is_shown_journalled_and_refused_outside_the_span():
    s = run_lines(Session(), BASE)
    assert s.execute("objective high: y - 2 @ 1 weight=5").message == "objective high: 1 term(s) at t=1"
    assert s.execute("show high").message.splitlines()[0] == \
        "objective high: minimize weight 5 times the square of its term at t=1 (a terminal cost)"
    assert "objective high: y - 2 @ 1 weight=5" in s.journal.replayable()
    with pytest.raises(StwError, match="objective time 2 is outside the animation span"):
        s.execute("objective late: y @ 2")
    assert "late" not in s.scene.objectives


# min ∫0^1 y''^2 ∓ W y(1) with y(0) = y'(0) = 0 (`maximize`: -W y(1)): y'''' = 0, so y = a t^2 + b t^3;
# the free end gives y''(1) = 0 (a = -3b) and 2 y'''(1) = ±W... for maximize y'''(1) = -W/2, so
# b = -W/12, a = W/4: y = W t^2/4 - W t^3/12, y(1) = W/6 and the objective W^2/12 - W^2/6 = -W^2/12.
# `minimize` mirrors it (y -> -y, same objective). A cubic: the spline holds it exactly.
def _signed_optimum(weight, sign):
    t = np.linspace(0, 1, 11)
    return sign * (weight * t ** 2 / 4 - weight * t ** 3 / 12), sign * weight / 6, -weight ** 2 / 12


@pytest.mark.parametrize("sense, sign", [("maximize", 1.0), ("minimize", -1.0)])
@pytest.mark.parametrize("weight", [6.0, 60.0])
def test_a_signed_terminal_cost_meets_the_euler_lagrange_optimum(sense, sign, weight):
    """Issue 53 item 2: a particle pushed to end as high (or low) as its effort allows."""
    s = run_lines(Session(), BASE + f"objective high: {sense} y @ 1 weight={weight!r}\nset tol_kkt 1e-12\niterate 20\n")
    assert s.runs[-1].converged
    curve, end, objective = _signed_optimum(weight, sign)
    assert s.scene.dofs["y"].curve.evaluate([1.0])[0] == pytest.approx(end, abs=1e-9)
    assert s.runs[-1].reports[-1].objective == pytest.approx(objective, rel=1e-9)
    assert np.allclose(s.scene.dofs["y"].curve.evaluate(np.linspace(0, 1, 11)), curve, atol=1e-9)


def test_maximize_integrated_matches_its_terminal_form():
    """∫0^1 y' dt = y(1) - y(0), and Gauss-Legendre integrates the spline's quadratic y' exactly:
    `maximize y'` over the span is `maximize y @ 1` (same motion and objective, -W^2/12)."""
    s = run_lines(Session(), BASE + "objective high: maximize y' weight=6\nset tol_kkt 1e-12\niterate 20\n")
    assert s.runs[-1].converged
    curve, end, objective = _signed_optimum(6.0, 1.0)
    assert s.runs[-1].reports[-1].objective == pytest.approx(objective, rel=1e-9)
    assert np.allclose(s.scene.dofs["y"].curve.evaluate(np.linspace(0, 1, 11)), curve, atol=1e-9)


@pytest.mark.parametrize("newton", ["exact", "auto"])
def test_maximize_a_nonlinear_term_uses_its_hessian(newton):
    """`maximize -(y - 2)^2 @ 1` is the squared terminal cost `y - 2 @ 1` written as a signed
    term: the same optimum (the test above's closed form), reached through the linear group's
    Hessian W ∇²e instead of the Gauss-Newton square. (`hessian=gauss_newton` leaves that
    curvature out, as it leaves out every constraint's: it crawls here, 40 steps unconverged.)"""
    weight = 100.0
    s = run_lines(Session(), BASE + f"backend scipy hessian={newton}\n"
                  f"objective high: maximize -(y - 2)^2 @ 1 weight={weight!r}\nset tol_kkt 1e-12\niterate 40\n")
    assert s.runs[-1].converged
    b, end = -weight / (3 + weight), 2 * weight / (3 + weight)
    assert s.scene.dofs["y"].curve.evaluate([1.0])[0] == pytest.approx(end, abs=1e-9)
    assert s.runs[-1].reports[-1].objective == pytest.approx(12 * b * b + weight * (end - 2) ** 2, rel=1e-9)


def test_a_signed_cost_is_shown_checked_and_journalled():
    s = run_lines(Session(), BASE)
    assert s.execute("objective high: maximize y @ 1 weight=5").message == "objective high: maximize its term at t=1"
    assert s.execute("show high").message.splitlines()[0] == (
        "objective high: maximize its term, weight 5, at t=1 (a terminal cost); it enters the merit "
        "as -5 times its value, not squared")
    assert "objective high: maximize y @ 1 weight=5" in s.journal.replayable()
    with pytest.raises(StwError, match="maximize takes one expression"):
        s.execute("objective two: maximize y, y'")
    assert "two" not in s.scene.objectives
    # a DOF may be named like the keyword: alone it is the expression (squared, as always)
    s.execute("dof maximize")
    assert s.execute("objective m: maximize").message == "objective m: 1 term(s)"
    assert s.scene.objectives["m"].sense is None


def test_an_unbounded_signed_cost_says_so_and_keeps_the_scene_usable():
    """Nothing bounds `maximize y @ 1` without an effort: the solve runs to its limit and says why."""
    s = run_lines(Session(), "time 0 1 knots=8\ndof y\nconstraint rest: y = 0, y' = 0 @ 0\n"
                  "objective run: maximize y @ 1\n")
    result = s.execute("iterate 12")
    assert "iteration limit reached" in result.message
    assert "the objective is still falling" in result.message and "unbounded" in result.message
    s.execute("objective fuel: y''")   # bounded now: the closed form above (W = 1)
    s.execute("set tol_kkt 1e-12")
    s.execute("iterate 40")
    assert s.runs[-1].converged
    assert s.scene.dofs["y"].curve.evaluate([1.0])[0] == pytest.approx(1 / 6, abs=1e-9)


def test_a_bounded_signed_cost_stopped_early_is_not_called_unbounded():
    """`maximize sin(y) @ 1` is bounded (by W): stopped after 3 falling steps (-239, -492, -492.7)
    it is not called unbounded, which only a fall to 1000 times the first objective is."""
    s = run_lines(Session(), BASE + "objective high: maximize sin(y) @ 1 weight=500\n")
    result = s.execute("iterate 3")
    objectives = [r.objective for r in s.runs[-1].reports]
    assert len(objectives) == 3 and objectives[0] > objectives[1] > objectives[2] > -500
    assert "iteration limit reached" in result.message and "still falling" not in result.message


@pytest.mark.parametrize("evaluation", ["native", "callback"])
def test_ipopt_meets_the_signed_optimum_too(evaluation):
    """Both of ipopt's paths: its own CasADi expressions (the signed rows lowered there) and
    stw's evaluations."""
    pytest.importorskip("casadi")
    s = run_lines(Session(), BASE + "objective high: maximize y @ 1 weight=6\n"
                  f"backend ipopt evaluation={evaluation}\niterate 30\n")
    assert s.runs[-1].converged
    curve, end, objective = _signed_optimum(6.0, 1.0)
    assert s.runs[-1].reports[-1].objective == pytest.approx(objective, rel=1e-8)
    assert np.allclose(s.scene.dofs["y"].curve.evaluate(np.linspace(0, 1, 11)), curve, atol=1e-8)


def test_torch_refuses_a_signed_cost_and_leaves_the_scene():
    pytest.importorskip("torch")
    s = run_lines(Session(), BASE + "objective high: maximize y @ 1\nbackend torch\n")
    before = s.scene.dofs["y"].curve.coef.copy()
    with pytest.raises(StwError, match="torch backend squares every objective term"):
        s.execute("iterate 5")
    assert np.array_equal(s.scene.dofs["y"].curve.coef, before)
