"""Motion that holds between the samples: the continuous-time check, exact instance placement,
adaptive instances, and windows that keep what holds outside them."""

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.interpolate import BSpline

import catalogue
from conftest import ROOT, SESSIONS, run_lines
from stw_tui.session.session import Session
from stw_tui.sos.continuous import check_scene
from stw_tui.sos.instances import exact_times
from stw_tui.sos.window import WindowProblem

FINE = np.linspace(0, 1, 100_001)


def test_dense_check_sees_what_the_instances_miss():
    # A wave whose zeros sit exactly on the 17 instances of `flat`: every instance holds, and
    # between them the curve reaches 0.1 (the peaks of sin at odd multiples of 1/32).
    s = run_lines(Session(), "time 0 1 knots=64\ndof x = 0.1*sin(16*pi*t)\n"
                             "constraint flat: x = 0 on [0, 1] samples=16\n")
    check = check_scene(s.scene).checks["flat"]
    truth = np.abs(s.scene.dofs["x"].curve.evaluate(FINE))   # an independent, brute-force grid
    assert check.instances < 2e-4                   # the spline's zeros are at the instances
    assert check.dense == pytest.approx(truth.max(), rel=1e-6)
    assert check.dense == pytest.approx(0.1, rel=1e-3)
    assert abs(np.sin(16 * np.pi * check.worst_t)) == pytest.approx(1, abs=1e-3)   # at a peak


def test_inequality_tangency_between_grid_points_is_found():
    # y = (t - 0.4321)^2 - 1e-5 dips below 0 by 1e-5 on a width of 6e-3 only.
    s = run_lines(Session(), "time 0 1 knots=4\ndof y = (t - 0.4321)^2 - 1e-5\n"
                             "constraint floor: y >= 0 on [0, 1] samples=4\n")
    check = check_scene(s.scene).checks["floor"]
    assert check.instances == 0.0
    assert check.dense == pytest.approx(1e-5, rel=1e-6)
    assert check.worst_t == pytest.approx(0.4321, abs=1e-5)   # a flat minimum: its place is vaguer


@pytest.mark.parametrize("r", [0, 1, 2])
@pytest.mark.parametrize("a, b", [(0.0, 1.0), (0.13, 0.71), (0.26, 0.33)])
def test_exact_times_determine_the_piecewise_polynomial(r, a, b):
    # Schoenberg-Whitney, checked independently: the design matrix of the degree 3-r splines that
    # live on [a, b] at these points has full column rank, so a combination of DOF derivatives
    # that vanishes there vanishes everywhere on [a, b].
    knots = np.r_[[0.0] * 3, np.sort(np.r_[np.linspace(0, 1, 9), 0.3, 0.55]), [1.0] * 3]
    breaks = np.unique(knots)
    points = exact_times(breaks, a, b, r)
    degree = 3 - r
    trimmed = knots[r:len(knots) - r]
    basis = BSpline.design_matrix(np.linspace(a, b, 400), trimmed, degree).toarray()
    alive = np.flatnonzero(np.abs(basis).sum(0) > 0)           # basis functions nonzero on [a, b]
    collocation = BSpline.design_matrix(points, trimmed, degree).toarray()[:, alive]
    assert np.linalg.matrix_rank(collocation) == alive.size == points.size


def test_linear_constraints_hold_everywhere_with_few_instances():
    s = run_lines(Session(), """time 0 1 knots=10 samples=40
const g = 9.81
dof x, y
constraint start: x = 0, y = 0, x' = 0, y' = 3 @ 0
constraint track: x = 0.5 + 0.2*t on [0.33, 0.71]
constraint flight: y'' + g = 0 on [0.25, 1]
objective effort: x'', y''
iterate 20
""")
    assert s.runs[-1].converged
    x, y = s.scene.dofs["x"].curve, s.scene.dofs["y"].curve
    inside = FINE[(FINE >= 0.33) & (FINE <= 0.71)]
    # Exact up to the solve's instance tolerance (1e-8) times the points' Lebesgue constant.
    gap = np.abs(x.evaluate(inside) - (0.5 + 0.2 * inside)).max()
    assert gap < 1e-7
    assert check_scene(s.scene).checks["track"].dense == pytest.approx(gap, rel=1e-3)
    air = FINE[FINE >= 0.25]
    assert np.abs(y.evaluate(air, 2) + 9.81).max() < 1e-7
    groups = {g.label: g.n for g in WindowProblem(s.scene).groups}
    assert groups["flight"] == 9        # the knots 0.3 .. 1 and 0.25: not the 31 uniform samples
    assert groups["track"] == 2 + 4 + 2  # 0.33 and 0.71, the knots 0.4 .. 0.7, a midpoint at each end


def test_subexpression_velocity_is_the_derivative_of_its_curve():
    s = run_lines(Session(), """time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  S revolute a=0.5 mass=1.0
  E revolute a=0.4 mass=0.7
end
dof S = t*t
dof E = 0.3*sin(2*t)
let h = arm.tip.y
""")
    t = np.array([0.3, 0.5, 0.8])
    from stw_tui.sym.symbols import named_symbol

    def tip_y(times):   # forward kinematics by hand, from the DOF curves
        S, E = (s.scene.dofs[n].curve.evaluate(times) for n in ("S", "E"))
        return 0.5 * np.sin(S) + 0.4 * np.sin(S + E)
    step = 1e-4
    fd1 = (tip_y(t + step) - tip_y(t - step)) / (2 * step)
    fd2 = (tip_y(t + step) - 2 * tip_y(t) + tip_y(t - step)) / step**2
    assert np.allclose(s.scene.evaluate(named_symbol("arm.tip.y'"), t), fd1, atol=1e-7)
    assert np.allclose(s.scene.evaluate(named_symbol("h''"), t), fd2, atol=1e-5)


PIN = """time 0 1 knots=20
dof x = 0.3
constraint pin: x = 0.3 @ 0.3
constraint lift: x = 1 @ 0.5
objective smooth: x''
window mid [0.4, 0.6]
iterate 20
"""


def test_a_window_cannot_break_a_constraint_just_outside_it():
    # The window [0.4, 0.6] frees control points whose support reaches 3 spans (0.15) past it,
    # down to 0.25: the pin at 0.3, outside the window but inside that reach, must hold (with
    # instances only inside the window, x(0.3) moves).
    s = run_lines(Session(), PIN)
    assert s.runs[-1].converged
    x = s.scene.dofs["x"].curve
    assert x.evaluate([0.5])[0] == pytest.approx(1, abs=1e-8)
    assert x.evaluate([0.3])[0] == pytest.approx(0.3, abs=1e-8)


def _held(report, tol):
    return {name for name, c in report.checks.items() if c.dense <= tol}


@pytest.mark.parametrize("problem", catalogue.problems(*catalogue.QUICK), ids=str)
def test_random_windows_keep_what_holds(problem):
    rng = np.random.default_rng(11)
    s = Session()
    s.run_file(problem.path)
    scene = s.scene
    objective = next(iter(scene.objectives))
    for k in range(3):
        a = rng.uniform(scene.t0, scene.t1 - 0.2 * (scene.t1 - scene.t0))
        b = a + rng.uniform(0.1, 0.3) * (scene.t1 - scene.t0)
        dofs = rng.choice(list(scene.dofs), size=rng.integers(1, len(scene.dofs) + 1), replace=False)
        tol = s.scene.settings["dense_tol"]
        before = _held(check_scene(s.scene), tol)
        s.execute(f"weight {objective} {1 + k}")   # something for the window to re-solve
        s.execute(f"window w{k} dofs={','.join(dofs)} [{a:.4f}, {min(b, scene.t1):.4f}]")
        s.execute("iterate 30")
        after = check_scene(s.scene)
        assert s.runs[-1].converged
        broken = {n for n in before if after.checks[n].dense > tol}
        assert not broken, (problem.name, k, {n: after.checks[n] for n in broken})
        s.execute("use all")


ADAPT = """time 0 2 knots=16 samples=8
const m = 1, g = 9.81
dof y = 0.5
constraint start: y = 0.5, y' = -3 @ 0
constraint goal:  y = 0.5, y' = 0 @ 2
constraint floor: y >= 0 on [0, 2]
objective thrust: m*y'' + m*g
"""


def test_adaptive_instances_fix_what_the_samples_missed():
    s = run_lines(Session(), ADAPT + "iterate 30 adapt=0\n")
    plain = check_scene(s.scene).checks["floor"]
    assert plain.instances <= 1e-8 and plain.dense > 1e-4     # the curve dips between samples
    outcome = s.execute("iterate 30")
    assert "added" in outcome.message and s.scene.extra_instances["floor"]
    fixed = check_scene(s.scene).checks["floor"]
    y = s.scene.dofs["y"].curve.evaluate(np.linspace(0, 2, 200_001))
    assert fixed.dense <= 1e-6 and y.min() >= -1e-6
    # The journal replays to the same motion, and a stopped adaptive solve journals what it kept.
    replay = run_lines(Session(), "\n".join(s.journal.replayable()))
    assert np.array_equal(replay.scene.coefficient_vector(), s.scene.coefficient_vector())


def test_a_stopped_adaptive_round_is_undone_and_journalled_as_what_was_kept(monkeypatch):
    from dataclasses import replace

    from stw_tui.session import interpreter
    from stw_tui.sos.backend import Status

    s = run_lines(Session(), ADAPT)
    real, calls = interpreter.run_iterations, []

    def stop_the_re_solve(backend, problem, start, n, settings, on_report=None, **hooks):
        calls.append(n)
        if len(calls) == 1:
            return real(backend, problem, start, n, settings, on_report, **hooks)
        # The user presses Esc at the re-solve's first iteration boundary.
        return replace(real(backend, problem, start, 1, settings, on_report, **hooks), status=Status.STOPPED)
    monkeypatch.setattr(interpreter, "run_iterations", stop_the_re_solve)
    outcome = s.execute("iterate 30")
    assert len(calls) == 2 and "undid a re-solve" in outcome.message
    assert s.journal.replayable()[-1] == "iterate 30 adapt=0"    # what was kept: the plain solve
    assert not s.scene.extra_instances
    monkeypatch.undo()
    replay = run_lines(Session(), "\n".join(s.journal.replayable()))
    assert np.array_equal(replay.scene.coefficient_vector(), s.scene.coefficient_vector())


def test_print_names_a_constraint_and_json_reports_the_dense_check():
    s = run_lines(Session(), PIN)
    s.execute("print pin")
    assert s.prints[-1].value["dense"] <= 1e-8
    out = subprocess.run([sys.executable, "-m", "stw_tui.cli.main", "run", str(SESSIONS / "point_mass_2d.stw"),
                          "--json"], capture_output=True, text=True, check=True, cwd=ROOT)
    data = json.loads(out.stdout)
    assert data["dense_violation"] <= 1e-6 and data["dense_ok"]
    floor = data["constraints"]["floor"]
    assert set(floor) >= {"instances", "dense", "worst_t"} and floor["dense"] <= 1e-6


def test_instances_command_and_its_errors():
    from stw_tui.sym.errors import StwError

    s = run_lines(Session(), PIN.replace("iterate 20\n", "constraint low: x <= 2 on [0.1, 0.9]\n"))
    s.execute("instances low add 0.5, 0.45")
    assert s.scene.extra_instances["low"] == (0.45, 0.5)
    assert 0.45 in WindowProblem(s.scene).groups[-1].times or any(
        0.45 in g.times for g in WindowProblem(s.scene).groups if g.source == "low")
    with pytest.raises(StwError, match="no constraint"):
        s.execute("instances nothing add 0.5")
    with pytest.raises(StwError, match="outside"):
        s.execute("instances low add 0.95")
    with pytest.raises(StwError, match="instant"):
        s.execute("instances lift add 0.5")
    s.execute("instances low clear")
    assert "low" not in s.scene.extra_instances


def test_arm_throw_flight_holds_after_the_release_window():
    # Once, a window around the release left `BY'' + g` at 0.87 just outside it (t = 0.84-0.91),
    # and the equations panel showed '?' for it until `use all`.
    s = Session()
    s.run_file(SESSIONS / "arm_throw.stw")
    assert s.scene.active_window != "all"
    s.execute("print B_flight")
    assert s.prints[-1].value["dense"] <= 1e-6
    s.execute("use all")
    t = np.linspace(0.55, 1.5, 20_001)
    assert np.abs(s.scene.dofs["BY"].curve.evaluate(t, 2) + 9.81).max() <= 1e-6


def test_a_triple_knot_lets_the_velocity_jump_and_linear_constraints_stay_exact():
    # A point mass kicked off the ground at t = 0.5: an impulse, so its velocity jumps there.
    s = run_lines(Session(), """time 0 1 knots=8
const g = 9.81
dof y
refine y @ 0.5 multiplicity=3
constraint rest:   y = 0, y' = 0 @ 0
constraint ground: y = 0 on [0, 0.5]
constraint flight: y'' + g = 0 on [0.5, 1]
constraint top:    y = 0.3 @ 0.75
objective effort:  y''
iterate 20
""")
    assert s.runs[-1].converged
    y = s.scene.dofs["y"].curve
    assert y.n_coef == 13                                     # 8 spans + 3, and two more knots
    before, after = np.linspace(0, 0.5, 5001), np.linspace(0.5, 1, 5001)
    assert np.abs(y.evaluate(before)).max() < 1e-9            # planted until 0.5 ...
    assert np.abs(y.evaluate(after, 2) + 9.81).max() < 1e-7   # ... then ballistic at once
    # The take-off velocity of a parabola through (0.5, 0) and (0.75, 0.3) under g.
    assert y.evaluate([0.5], 1)[0] == pytest.approx(0.3 / 0.25 + 9.81 * 0.25 / 2, abs=1e-7)
    assert check_scene(s.scene).dense_violation <= 1e-7


def test_exact_times_pin_both_sides_of_a_repeated_knot():
    # A double knot inside [a, b] adds a degree of freedom to the piecewise polynomial there.
    knots = np.r_[[0.0] * 4, 0.25, 0.5, 0.5, 0.75, [1.0] * 4]
    for r in (0, 1, 2):
        points = exact_times(np.unique(knots), 0.1, 0.9, r, repeated=np.array([0.5]))
        trimmed = knots[r:len(knots) - r]
        basis = BSpline.design_matrix(np.linspace(0.1, 0.9, 400), trimmed, 3 - r).toarray()
        alive = np.flatnonzero(np.abs(basis).sum(0) > 0)
        collocation = BSpline.design_matrix(points, trimmed, 3 - r).toarray()[:, alive]
        assert np.linalg.matrix_rank(collocation) == alive.size


def test_a_phase_ending_at_a_repeated_knot_is_held_on_its_own_side():
    # The ground phase ends at the take-off knot 0.5, where curves are evaluated from the right
    # (the flight side); its last instance and its check must see the ground side.
    s = run_lines(Session(), """time 0 1 knots=8
const g = 9.81
dof y
refine y @ 0.5 multiplicity=2
constraint rest:   y = 0, y' = 0 @ 0
constraint ground: y'' = 0 on [0, 0.5]
constraint flight: y'' + g = 0 on [0.5, 1]
objective effort:  y
iterate 20
""")
    assert s.runs[-1].converged
    y = s.scene.dofs["y"].curve
    assert np.abs(y.evaluate(np.linspace(0, 0.5, 5001)[:-1], 2)).max() < 1e-8   # planted up to 0.5
    assert y.evaluate([0.5], 2)[0] == pytest.approx(-9.81, abs=1e-8)             # flying from 0.5
    report = check_scene(s.scene)
    assert report.checks["ground"].dense < 1e-8 and report.checks["flight"].dense < 1e-8


def test_a_phase_ending_at_a_knot_within_rounding_of_its_end_is_held_on_its_own_side():
    # 78 spans over [0, 3.9]: the knot meant at 3.2 is 0.05 * 64 = 3.1999999999999997, and
    # `refine @ 3.2` doubles that knot. The flight [2.5, 3.2] must still be judged (and held) from
    # its own side of it, not from the float just below 3.2, which is the knot itself.
    s = run_lines(Session(), """time 0 3.9 knots=78
const g = 9.81
dof y
refine y @ 3.2 multiplicity=2
constraint rest:   y = 0, y' = 0 @ 2.5
constraint flight: y'' + g = 0 on [2.5, 3.2]
constraint ground: y'' = 0 on [3.2, 3.9]
objective effort:  y
iterate 20
""")
    assert s.runs[-1].converged
    y = s.scene.dofs["y"].curve
    knot = y.knots[np.abs(y.knots - 3.2) < 1e-9]
    assert knot.size == 2 and knot[0] != 3.2      # the case: the double knot is not 3.2 itself
    assert np.abs(y.evaluate(np.linspace(2.5, 3.2, 7001)[:-1], 2) + 9.81).max() < 1e-8
    assert np.abs(y.evaluate(np.linspace(3.2, 3.9, 7001), 2)).max() < 1e-8
    report = check_scene(s.scene)
    assert report.checks["flight"].dense < 1e-8 and report.checks["ground"].dense < 1e-8


def test_bounds_hold_everywhere_because_they_bound_the_control_points():
    # An objective pulls x towards a sine that leaves [-1, 1]; the bounds hold on the control
    # points, so by the convex hull of a B-spline the curve stays inside everywhere, not only at
    # samples: checked here on a fine grid, independently of the dense check.
    s = run_lines(Session(), """time 0 1 knots=10
dof x lo=-1 hi=1
objective pull: x - 1.5*sin(2*pi*t)
iterate 30
""")
    assert s.runs[-1].converged
    curve = s.scene.dofs["x"].curve
    values = curve.evaluate(FINE)
    assert values.max() <= 1 + 1e-9 and values.min() >= -1 - 1e-9
    assert values.max() > 0.99 and values.min() < -0.99                 # it does reach the bounds
    assert np.all(curve.coef <= 1 + 1e-9) and np.all(curve.coef >= -1 - 1e-9)
    check = check_scene(s.scene).checks["x.bounds"]
    assert check.dense <= 1e-9 and check.instances <= 1e-9
    assert not s.scene.extra_instances                                   # nothing had to be added


def test_a_bound_is_checked_on_the_curve_exactly_whether_or_not_its_control_points_keep_it():
    # Control points inside [lo, hi]: the check reports no violation and no worst time without
    # sampling the curve (convex hull), and 100k samples of the curve agree. One control point
    # pushed past hi: the curve goes past it by less than the control point, and the check finds
    # where, as a brute-force grid does (scipy's own BSpline, not stw's evaluation).
    s = run_lines(Session(), "time 0 1 knots=10\ndof x lo=-1 hi=1\n")
    dof = s.scene.dofs["x"]
    inside = 0.999 * np.sin(np.linspace(0.0, 3 * np.pi, dof.curve.n_coef))
    assert np.isclose(np.abs(inside).max(), 0.999, atol=1e-3)
    dof.curve = dof.curve.with_coef(inside)
    check = check_scene(s.scene).checks["x.bounds"]
    assert (check.instances, check.dense, check.worst_t) == (0.0, 0.0, None)
    values = BSpline(dof.curve.knots, inside, 3)(FINE)
    assert values.max() <= 1 and values.min() >= -1

    past = inside.copy()
    past[4:7] = 1.05, 1.1, 1.05
    dof.curve = dof.curve.with_coef(past)
    check = check_scene(s.scene).checks["x.bounds"]
    values = BSpline(dof.curve.knots, past, 3)(FINE)
    worst = int(np.argmax(values))
    assert check.instances == pytest.approx(0.1, abs=1e-12)
    assert 0 < values[worst] - 1 < 0.1                         # the curve stays inside the hull
    # densely, the motion's own excursion (0.0833 here), not the control point's: a bound's
    # instances are not points of the curve (measured: the 100k grid's to the last bit)
    assert check.dense == pytest.approx(values[worst] - 1, abs=1e-9)
    assert check.worst_t == pytest.approx(FINE[worst], abs=1e-4)


def test_condition_tree_is_evaluated_like_its_boolean_formula():
    """The one `when` evaluator (numpy here, torch in the torch backend) against the formula
    written out with numpy's own operators."""
    import sympy as sp

    from stw_tui.sos.window import evaluate_condition_tree, numpy_filled, relation_nodes

    x, y = sp.symbols("x y", real=True)
    tree = sp.Or(sp.And(x > 0, sp.Not(sp.And(y <= 1, x < 2))), sp.Eq(x, y), sp.Ne(y, 2) & (x < -1))
    assert tree.has(sp.Not)   # sympy keeps a negated conjunction as it is
    rng = np.random.default_rng(3)
    xs, ys = rng.integers(-3, 4, 200).astype(float), rng.integers(-3, 4, 200).astype(float)
    leaves = {node: {x: xs, y: ys}[node.lhs] - (ys if node.rhs == y else float(node.rhs))
              for node in relation_nodes(tree)}
    want = ((xs > 0) & ~((ys <= 1) & (xs < 2))) | (xs == ys) | ((ys != 2) & (xs < -1))
    got = evaluate_condition_tree(tree, leaves, numpy_filled(xs.size))
    assert got.dtype == bool and np.array_equal(got, want) and want.any() and not want.all()
    assert evaluate_condition_tree(sp.true, {}, numpy_filled(4)).tolist() == [True] * 4
    assert evaluate_condition_tree(sp.false, {}, numpy_filled(4)).tolist() == [False] * 4


def test_a_nonlinear_ode_holds_between_instances_only_to_the_discretization_error_which_refining_shrinks_as_h2():
    # A pendulum collocated on the knots (th'' + g sin th = 0, one instance per knot, plus the
    # start): the spline has exactly as many control points as rows, so the instances hold to
    # round-off, but th'' + g sin(th) of a cubic spline cannot vanish between them. That gap is
    # discretization error, not a solver failure: halving the knot spacing divides the dense
    # violation by ~4 (h²), and the motion converges to the true pendulum (scipy's solve_ivp,
    # an independent integrator) at the same rate. Adding instances cannot help (the rows would
    # outnumber the control points); refining the knots does. This is why the acrobat's flight
    # torque and planted foot, nonlinear in its DOF, keep a dense violation far above 1e-6.
    from scipy.integrate import solve_ivp

    g, t = 9.81, np.linspace(0, 2, 401)
    exact = solve_ivp(lambda _, y: [y[1], -g * np.sin(y[0])], (0, 2), [1.0, 0.0], t_eval=t,
                      rtol=1e-12, atol=1e-12).y[0]
    dense, error = [], []
    for knots in (16, 32, 64):
        s = Session()
        s.run_text(f"""time 0 2 knots={knots} samples={knots}
dof th = 1
constraint start: th = 1, th' = 0 @ 0
constraint swing: th'' + {g}*sin(th) = 0 on [0, 2]
set adaptive off
iterate 30
""")
        assert s.runs[-1].converged and s.runs[-1].reports[-1].max_violation <= 1e-10
        dense.append(check_scene(s.scene).checks["swing"].dense)
        error.append(np.abs(s.scene.dofs["th"].curve.evaluate(t) - exact).max())
    assert dense[-1] > 1e-3                                        # far above any dense_tol
    for coarse, fine in zip(dense, dense[1:]):
        assert 3.5 <= coarse / fine <= 4.5, dense
    for coarse, fine in zip(error, error[1:]):
        assert 3.0 <= coarse / fine <= 5.0, error


def test_exact_degree_is_sympys_answer_and_nonlinear_relations_skip_its_derivatives(monkeypatch):
    """Which relations get exact instances (affine in DOF quantities with constant coefficients):
    the answers sympy's derivatives give, affine relations in disguise included (x(1 + x) - x²,
    cos²q + sin²q + q''). A relation whose compiled term has a second derivative in DOF
    quantities is refused without sympy's derivatives (which took half of luxo.stw's replay on its
    equations of motion); one that is only time-varying (t q) is left to them."""
    from stw_tui.sos import instances

    s = Session()
    s.run_text("time 0 1 knots=6\nconst g = 9.81\ndof x\ndof q\n"
               "constraint a: x'' + g = 0 on [0, 1]\n"
               "constraint b: 2*x' - 3*q = 1 on [0, 1]\n"
               "constraint c: x*(1 + x) - x^2 = 0.5 on [0, 1]\n"
               "constraint d: cos(q)^2 + sin(q)^2 + q'' = 1 on [0, 1]\n"
               "constraint e: sin(q) + q'' = 0 on [0, 1]\n"
               "constraint f: q*q' = 0 on [0, 1]\n"
               "constraint h: t*q = 0 on [0, 1]\n"
               "constraint i: x'' >= -g on [0, 1]\n"
               "constraint j: x >= 0 on [0, 1]\n"
               "constraint k: abs(x'') <= 3 on [0, 1]\n")
    scene = s.scene
    want = {"a": 2, "b": 1, "c": 0, "d": 2, "e": None, "f": None, "h": None, "i": 2, "j": None, "k": None}
    instances._exact_degree.cache_clear()
    derivatives = []
    diff = instances.sp.diff
    monkeypatch.setattr(instances.sp, "diff", lambda *a: derivatives.append(a) or diff(*a))
    for name, degree in want.items():
        (relation,) = scene.constraints[name].relations
        before = len(derivatives)
        assert instances.exact_degree(scene, relation.expr, relation.kind) == degree, name
        if name in "ef":
            assert len(derivatives) == before, name     # the screen refused it


def _samples_by_check(scene, cold: bool):
    """Every check's (instances, grid, grid violations), with the kept relation times used or
    (``cold``) forgotten first: what the check works out from scratch."""
    from stw_tui.sos import continuous, instances

    if cold:
        instances._KEPT.clear()
    return {name: [(s.t_inst, s.t_grid, s.v_grid) for s in samples]
            for name, samples, _ in continuous._all_samples(scene)}


@pytest.mark.parametrize("change", [
    "refine y [0.5, 1]",                                   # a knot span split: a finer grid
    "instances floor add 0.37",                            # an added instance
    "constraint floor: y >= 0 on [0, 2] samples=5",        # its own density
    "time 0 2 knots=16 samples=10",                        # the scene's density
    "constraint floor: y >= 0 on [0, 1.5]",                 # its interval
])
def test_the_kept_relation_times_follow_every_change_of_instances_or_grid(change):
    s = run_lines(Session(), ADAPT)
    before = _samples_by_check(s.scene, cold=False)   # the times are kept for this structure
    run_lines(s, change + "\n")
    warm, cold = _samples_by_check(s.scene, cold=False), _samples_by_check(s.scene, cold=True)
    assert warm.keys() == cold.keys() == before.keys()
    for name in cold:
        for (ti, tg, vg), (ci, cg, cv) in zip(warm[name], cold[name]):
            assert np.array_equal(ti, ci) and np.array_equal(tg, cg) and np.array_equal(vg, cv)
    # the change moved the floor's instances or its grid (or its values): kept ones would show
    (ti, tg, vg), = before["floor"]
    (ci, cg, cv), = cold["floor"]
    assert not (np.array_equal(ti, ci) and np.array_equal(tg, cg) and np.array_equal(vg, cv))


def test_a_relation_evaluated_on_part_of_shared_times_gives_its_values_at_those_times_alone():
    from stw_tui.sos.spline import SharedTimes

    s = run_lines(Session(), ADAPT + "iterate 5 adapt=0\n")
    rng = np.random.default_rng(3)
    times = [np.sort(rng.uniform(0, 2, n)) for n in (1, 17, 300)]
    shared = SharedTimes(np.concatenate(times), keep=False)
    exprs = [rel.expr for c in s.scene.constraints.values() for rel in c.relations]
    exprs += [e for o in s.scene.objectives.values() for e in o.exprs]   # m*y'' + m*g
    start = 0
    for t in times:
        for expr in exprs:
            values = s.scene.evaluator(expr)
            assert np.array_equal(values.at(shared, slice(start, start + t.size)), values(t))
        start += t.size


def test_a_failure_names_the_constraints_own_dense_tol():
    # A constraint with dense_tol=0.001 that fails between its instances is reported with its own
    # tolerance, not only the scene's (1e-6), which it is not held to.
    s = run_lines(Session(), """time 0 1 knots=4 samples=4
dof x
constraint c: x - sin(9*t) = 0 on [0, 1] dense_tol=0.001
objective e: x''
set adaptive off
""")
    message = s.execute("iterate 20").message
    assert "c 3.2e-01 at t=0.8875 (its dense_tol 0.001)" in message, message


def test_a_relation_on_exact_instances_holds_between_double_knots():
    # x = 0 on a cubic whose three inside knots are all double (C1 there): a space of 10
    # dimensions, whose exact instances were 9 points (the pieces' shared midpoints). The solve
    # "converged" with x 0.025 from 0 between them, and no refinement looks at exact instances.
    s = run_lines(Session(), """time 0 1 knots=4
dof x = sin(7*t) + t
refine x @ 0.25 multiplicity=2
refine x @ 0.5 multiplicity=2
refine x @ 0.75 multiplicity=2
constraint c: x = 0 on [0, 1]
iterate 20
""")
    assert s.runs[-1].converged
    assert np.abs(BSpline(s.scene.dofs["x"].curve.knots, s.scene.dofs["x"].curve.coef, 3)(FINE)).max() < 1e-12
    assert check_scene(s.scene).checks["c"].dense < 1e-12      # measured 2.4e-16
