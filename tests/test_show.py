"""The symbolic console: `show NAME`, `show EXPR [@ T]` and `cse`. Each output is checked against
what the scene holds, derived independently (instance times, knots, the verb's own lines, a
hand-expanded subexpression, symengine's CSE rebuilt into the term)."""

import numpy as np
import pytest
import sympy as sp

import catalogue
from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.session.show import common_subexpressions
from stw_tui.sym.errors import SourceError, StwError

ARM = catalogue.problem("analytic_arm3").text + """dof BX, BY = 0.5*t lo=-2
dof CX, CY
hold C at arm.tip on [0, 0.55] mass=0.5
ballistic C on [0.55, 1.5]
let lift = BY'' + g
constraint up: lift >= 0 on [0, 1] weight=3
objective effort: tau_WRIST
"""


@pytest.fixture(scope="module")
def arm():
    return run_lines(Session(), ARM)


def show(session, line):
    return session.execute(line).message


def test_show_a_verb_prints_its_line_and_the_constraints_it_expanded_into(arm):
    text = show(arm, "show C_held").splitlines()
    assert text[0] == "hold C at arm.tip on [0, 0.55] mass=0.5"
    assert text[1:3] == ["  CX is arm.tip.x on [0, 0.55]", "  CY is arm.tip.y on [0, 0.55]"]
    assert text[3] == "  its mass loads tau_SHOULDER, tau_ELBOW, tau_WRIST there"
    members = arm.scene.verbs["C_held"][1]
    assert members == ("C_released",)
    assert text[5:] == ["  " + arm.scene.constraints["C_released"].text]
    assert show(arm, "show C_flight").splitlines()[2] == "  constraint C_flight: CX'' = 0, CY'' + g = 0 on [0.55, 1.5]"
    # A part of a verb says which verb made it; one written by hand does not.
    assert show(arm, "show C_released").splitlines()[-1] == \
        "  made by the verb `hold C at arm.tip on [0, 0.55] mass=0.5` (`delete C_held` removes the group)"
    assert "made by" not in show(arm, "show up") and "made by" not in show(arm, "show effort")
    # The held DOF says where it is the hand's point; its flight reads its own curve alone.
    assert show(arm, "show CX").splitlines()[-1] == \
        "  is arm.tip.x on [0, 0.55] (`hold C at arm.tip on [0, 0.55] mass=0.5`): its curve is read outside that only"
    assert "Piecewise" not in show(arm, "show C_flight") and "SHOULDER" not in show(arm, "show C_flight")


def test_show_a_constraint_gives_scope_weight_instances_and_the_compiled_relation(arm):
    text = show(arm, "show up")
    # lift >= 0 uses a subexpression of BY'' (affine, degree 1 inequality -> not exact): uniform
    # samples, 24 per 1.5 s, so 16 spans on [0, 1] and 17 instances.
    assert text.splitlines()[0] == "constraint up on [0, 1], weight 3, 17 instance(s)"
    assert "  lift >= 0" in text
    assert "BY'' + g  >= 0" in text            # as compiled: the subexpression substituted
    # B_released holds at an instant: one instance per relation.
    assert show(arm, "show C_released").splitlines()[0] == "constraint C_released @ 0.55, weight 1, 4 instance(s)"


def test_show_an_objective_and_a_derived_force_print_their_expanded_form(arm):
    text = show(arm, "show effort")
    assert text.splitlines()[0].startswith("objective effort: minimize weight 1 times the integral over [0, 1.5]")
    assert "as compiled:" in text and "WRIST''" in text
    derived = show(arm, "show tau_WRIST")
    assert derived.startswith("tau_WRIST (derived from linkage arm) = ")
    # The simplified form printed equals the definition (checked numerically at random states).
    simplified_line = derived.split("simplified:\n", 1)[1].strip()
    names = sorted({s.name for s in arm.scene.derived["tau_WRIST"].free_symbols})
    symbols = {n: sp.Symbol(n, real=True) for n in names}
    printed = sp.sympify(simplified_line.replace("'", "_p"),   # stw's own output, read back
                         locals={n.replace("'", "_p"): s for n, s in symbols.items()})
    rng = np.random.default_rng(1)
    for _ in range(5):
        point = {symbols[n]: rng.normal() for n in names}
        assert float(printed.xreplace(point)) == pytest.approx(
            float(arm.scene.derived["tau_WRIST"].xreplace(point)), rel=1e-9, abs=1e-12)


def test_show_a_dof_gives_its_knots_control_points_and_bounds(arm):
    text = show(arm, "show BY").splitlines()
    curve = arm.scene.dofs["BY"].curve
    assert text[0] == (f"dof BY: cubic B-spline on [0, 1.5], 24 span(s), {curve.n_coef} control points, "
                       "lo=-2 (on its control points, so everywhere)")
    assert text[1].startswith("  knots: 0 (x4), 0.0625, ") and text[1].endswith("1.5 (x4)")
    values = [float(v) for v in text[2].split(": ", 1)[1].split(", ")]
    np.testing.assert_allclose(values, curve.coef, rtol=1e-5, atol=1e-9)


def test_show_expression_at_a_time_adds_its_value(arm):
    text = show(arm, "show lift*2 @ 0.5")
    by = arm.scene.dofs["BY"].curve.evaluate(np.array([0.5]), 2)[0]
    assert text.splitlines()[0] == "lift*2 ="
    assert text.splitlines()[-1] == f"  @ 0.5 = {2 * (by + 9.81):.10g}"
    assert show(arm, "show g") == "const g = 9.81"
    assert show(arm, "show lift") == "lift (let) = BY'' + g"


def test_cse_rebuilds_the_term_it_splits(arm):
    text = show(arm, "cse tau_ELBOW")
    count = int(text.split(" ", 1)[0])
    assert count > 3
    replacements, reduced = common_subexpressions([arm.scene.expand(sp.Symbol("tau_ELBOW", real=True))])
    rebuilt = reduced[0]
    for symbol, value in reversed(replacements):
        rebuilt = rebuilt.xreplace({symbol: value})
    term = arm.scene.expand(sp.Symbol("tau_ELBOW", real=True))
    rng = np.random.default_rng(2)
    for _ in range(5):   # the same function: equal at random states (floats: not symbolically)
        values = {s.name: rng.normal() for s in term.free_symbols}
        at = lambda e: float(e.xreplace({s: values[s.name] for s in e.free_symbols}))
        assert at(rebuilt) == pytest.approx(at(term), rel=1e-12, abs=1e-12)
    # and what cse prints is that split: the same count, the first shared piece
    assert text.splitlines()[1] == f"  x0 = {sp.sstr(replacements[0][1])}"
    assert show(arm, "cse sin(BX)*BY + sin(BX)^2").splitlines()[1] == "  x0 = sin(BX)"


def test_show_is_read_only_not_a_step_and_bad_names_are_refused(arm):
    steps = len(arm.history.undo_steps)
    show(arm, "show effort")
    show(arm, "cse effort")
    assert len(arm.history.undo_steps) == steps
    with pytest.raises(StwError, match="nothing named 'nope' to show"):
        arm.execute("show nope")
    with pytest.raises(SourceError):
        arm.execute("show BX +")
    with pytest.raises(StwError, match="outside the animation span"):
        arm.execute("show BX @ 7")
    assert "show NAME" in arm.execute("help show").message


def test_show_diff_is_the_partial_derivative_of_the_expanded_expression(arm):
    text = show(arm, "show diff(tau_ELBOW, ELBOW'') @ 0.4")
    assert text.splitlines()[0] == "diff(tau_ELBOW, ELBOW'') ="
    # The coefficient of ELBOW'' in tau_ELBOW is the mass-matrix entry M[ELBOW, ELBOW], here
    # derived by hand for rods: I_c + m_2 (a_2/2)^2 + (I_3c + m_3 (a_3/2)^2) + m_3 a_2^2
    # + 2 m_3 a_2 (a_3/2) cos(WRIST), with I_c = m a^2/12.
    m2, a2, m3, a3 = 1.5, 0.30, 0.5, 0.15
    wrist = arm.scene.dofs["WRIST"].curve.evaluate(np.array([0.4]))[0]
    expected = (m2 * a2**2 / 3 + m3 * a3**2 / 3 + m3 * a2**2 + m3 * a2 * a3 * np.cos(wrist))
    # and the held 0.5 kg at the tip (t = 0.4 is inside its hold): m |tip - elbow|^2
    expected += 0.5 * (a2**2 + a3**2 + 2 * a2 * a3 * np.cos(wrist))
    value = float(text.splitlines()[-1].split("= ")[1])
    assert value == pytest.approx(expected, rel=1e-9)
    assert "(t < 0.55) & (t >= 0)" in text       # the held mass counts while it is held
    with pytest.raises(SourceError, match="one variable"):
        arm.execute("show diff(tau_ELBOW, 2*ELBOW)")
    with pytest.raises(StwError, match="not a subexpression"):
        arm.execute("show diff(tau_ELBOW, lift)")
