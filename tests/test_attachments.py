"""Attachments: a DOF read as an expression over part of the animation, folded to one side where
a relation's scope decides it (stw_tui.sos.attachments)."""

import numpy as np
import sympy as sp

from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.sos.attachments import restrict
from stw_tui.sym.symbols import TIME as t, dof_symbol, named_symbol

HELD, OWN = sp.Symbol("held"), sp.Symbol("own")
PIECE = sp.Piecewise((HELD, (t > 0.2) & (t < 0.5)), (OWN, True))


def test_an_interval_is_read_on_its_inside_and_an_instant_at_its_time():
    assert restrict(PIECE, 0.2, 0.5) == HELD          # the hold itself, its ends as limits from inside
    assert restrict(PIECE, 0.3, 0.4) == HELD
    assert restrict(PIECE, 0.5, 1.0) == OWN            # the flight after the release
    assert restrict(PIECE, 0.0, 0.2) == OWN
    assert restrict(PIECE, 0.5, 0.5) == OWN            # the release instant reads the own curve
    assert restrict(PIECE, 0.2, 0.2) == OWN            # and so does the catch
    assert restrict(PIECE, 0.3, 0.3) == HELD
    assert restrict(PIECE, 0.1, 0.6) == PIECE          # straddling: decided at each time
    closed = sp.Piecewise((HELD, (t >= 0) & (t < 0.5)), (OWN, True))   # a hold from the start
    assert restrict(closed, 0.0, 0.0) == HELD and restrict(closed, 0.0, 0.4) == HELD


def test_a_held_object_reads_as_the_hand_inside_its_hold_and_as_its_curve_outside():
    s = run_lines(Session(), """time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.4 mass=1
end
dof SHOULDER = t
dof BX, BY
dof BX = 2 + t
dof BY = 3
hold B at arm.tip on [0.25, 0.75]
""")
    times = np.array([0.1, 0.25, 0.5, 0.75, 0.9])
    bx = s.scene.evaluate(named_symbol("BX"), times)
    # inside (0.25, 0.75) the hand: 0.4 cos(SHOULDER) with SHOULDER = t; the catch and the
    # release instants and outside: its own curve 2 + t
    assert np.allclose(bx, [2.1, 2.25, 0.4 * np.cos(0.5), 2.75, 2.9], atol=1e-12)
    assert np.allclose(s.scene.dof_values("BX", times, 1), [1, 1, -0.4 * np.sin(0.5), 1, 1], atol=1e-12)
    # A relation over the flight after the release stays linear in the ball's own curve ...
    flight = s.scene.expand(dof_symbol("BX", 2), (0.75, 1.0))
    assert flight == dof_symbol("BX", 2)
    # ... and one inside the hold reads the hand alone.
    inside = s.scene.expand(dof_symbol("BX"), (0.25, 0.75))
    assert inside.free_symbols == {dof_symbol("SHOULDER")}
    s.execute("delete B_held")                          # and the curve is the ball again
    assert np.allclose(s.scene.evaluate(named_symbol("BX"), times), 2 + times)
