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
