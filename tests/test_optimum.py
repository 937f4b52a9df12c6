"""Numerical results against analytic optima."""

import numpy as np
import pytest

import catalogue
from conftest import SESSIONS, run_lines
from stw_tui.session.session import Session

PARTICLE = catalogue.problem("analytic_particle").text + "backend scipy solver={solver}\niterate 20\n"


@pytest.mark.parametrize("solver", ["direct", "minres", "cg"])
def test_particle_optimum_is_the_cubic(solver):
    # Euler-Lagrange of ∫(m x'' + m g)^2 gives x'''' = 0: the cubic through the boundary
    # conditions, x = 3t^2 - 2t^3, which lies in the spline space, so it is reached exactly.
    s = run_lines(Session(), PARTICLE.format(solver=solver))
    t = np.linspace(0, 1, 101)
    curve = s.scene.dofs["x"].curve
    assert np.max(np.abs(curve.evaluate(t) - (3 * t**2 - 2 * t**3))) < 1e-8
    assert np.max(np.abs(curve.evaluate(t, 2) - (6 - 12 * t))) < 1e-6
    assert s.runs[-1].converged
    # The optimal fuel: ∫(6 - 12t + g)^2 dt = 12 + g^2 (the cross term integrates to 0).
    assert s.runs[-1].reports[-1].objective == pytest.approx(12 + 9.81**2, rel=1e-8)  # bounded by tol_violation=1e-8


DOUBLE_INTEGRATOR = catalogue.problem("analytic_double_integrator").text.replace("knots=10", "knots={knots}")


def _double_integrator(knots):
    s = run_lines(Session(), DOUBLE_INTEGRATOR.format(knots=knots) + "iterate 40\n")
    assert s.runs[-1].converged, s.runs[-1].status
    return s.runs[-1].reports[-1].objective, s


def test_double_integrator_with_state_bound_approaches_analytic_optimum():
    # Bryson & Ho's state-constrained double integrator: with l = 1/9 <= 1/6 the optimal
    # cost of ∫½u² is 4/(9l) = 4, the bound being active on [3l, 1-3l] = [1/3, 2/3].
    # The same 241 bound instances for every knot count, and nested spline spaces (5 ⊂ 10 ⊂ …),
    # so the discrete optimum can only improve as knots are added.
    errors = []
    for knots in (5, 10, 20, 40):
        cost, s = _double_integrator(knots)
        errors.append(cost - 4.0)
        x = s.scene.dofs["x"].curve.evaluate(np.linspace(0, 1, 241))
        assert x.max() <= 1 / 9 + 1e-9   # the bound holds at every instance
    assert all(later < earlier for earlier, later in zip(errors, errors[1:])), errors
    assert 0 < errors[-1] < 1e-4 * 4.0, errors


def test_point_mass_floor_is_active_and_respected():
    s = Session()
    s.run_file(SESSIONS / "point_mass_2d.stw")
    assert s.runs[-1].converged
    y = s.scene.dofs["y"].curve.evaluate(np.linspace(0, 2, 20001))   # in continuous time, not at samples
    assert y.min() >= -1e-6       # dense_tol: the floor holds between the instances too
    assert y.min() <= 1e-6        # and binds
    # With the floor only at its 65 uniform samples the optimum dipped below it between two;
    # the continuous-time check added an instance there.
    assert s.scene.extra_instances.get("floor")


def test_cat_chases_in_windows_but_runs_straight_with_full_knowledge():
    s = Session()
    s.run_file(SESSIONS / "cat_mouse.stw")
    prints = {(p.expr, p.t): p.value for p in s.prints}
    # Full spacetime, minimum ∫|c''|² with rest start and a catch at (3, 1): by symmetry of the
    # Euler-Lagrange solution each coordinate is the same cubic profile scaled, so the path is
    # the straight line y = x / 3.
    assert prints[("cy", 1.0)] == pytest.approx(prints[("cx", 1.0)] / 3, abs=1e-9)
    # Windowed (a window sliding by 0.25 s): heading for the mouse's present position, the cat
    # climbs far more steeply, is still behind the mouse (1.5, 1) at t = 0.5, never runs backwards
    # (checked on a fine grid), and catches the mouse within 1 cm.
    assert prints[("cy", 0.5)] / prints[("cx", 0.5)] > 0.5
    assert prints[("cx", 0.5)] < 1.5 and prints[("cy", 0.5)] < 1.0
    assert np.hypot(prints[("cx - mx", 2.0)], prints[("cy - my", 2.0)]) < 0.01
    speed = s.scene.dofs["cx"].curve.evaluate(np.linspace(0, 2, 20_001), 1)
    assert speed.min() >= -1e-12   # (zero at the rest start, up to rounding)
    assert len(s.runs) == 2 and all(run.converged for run in s.runs)
    assert len(s.runs[-1].reports) >= 7            # one solve at each of the 7 positions
