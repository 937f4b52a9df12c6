"""Tests that kill mutants mutmut found surviving in stw_tui/sos/ and stw_tui/sym/linkage/ (issue 56).

Each asserts real behaviour derived apart from the code under test (README, "Contributing:
mutation testing").
"""

from types import SimpleNamespace

import pytest

import numpy as np
import sympy as sp

from conftest import run_lines
from stw_tui.session.session import Session
from scipy.interpolate import BSpline

from stw_tui.sos.continuous import SNAP, ConstraintCheck, DenseReport, _snap, condition_holds, survey_failures
from stw_tui.sos.instances import (dofs_used, exact_degree, exact_times, extra_times, interval_cuts, merge_times,
                                   on_own_side, relation_times, repeated_knots, uniform_times)
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.symbols import dof_symbol
from stw_tui.sos.window import WindowProblem


# A one-link arm that holds a ball over [0.25, 0.75]: inside the hold BX, BY are the hand's point.
HELD = """time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.4 mass=1
end
dof SHOULDER = t
dof BX, BY
hold B at arm.tip on [0.25, 0.75]
"""


def test_uniform_samples_keep_the_scene_density_on_an_interval_away_from_zero():
    # 8 samples over an animation of 2 s is 4 per second, wherever the interval lies: [1, 2]
    # and [0.5, 1.5] get 4 steps each, [1.5, 2] two; samples=6 (per animation) gives [1, 2] 3.
    # (mutant: the interval's length read as b + a, 12 steps on [1, 2])
    scene = SimpleNamespace(t0=0.0, t1=2.0, sample_count=8)
    assert np.array_equal(uniform_times(scene, 1.0, 2.0), np.linspace(1.0, 2.0, 5))
    assert np.array_equal(uniform_times(scene, 0.5, 1.5), np.linspace(0.5, 1.5, 5))
    assert np.array_equal(uniform_times(scene, 1.5, 2.0), np.linspace(1.5, 2.0, 3))
    assert np.array_equal(uniform_times(scene, 1.0, 2.0, samples=6), np.linspace(1.0, 2.0, 4))
    # an animation that starts at 1 s has the same density (mutant: its length read as t1 + t0)
    later = SimpleNamespace(t0=1.0, t1=3.0, sample_count=8)
    assert np.array_equal(uniform_times(later, 2.0, 3.0), np.linspace(2.0, 3.0, 5))
    # an interval shorter than a step still has its two ends, and nothing between (mutant: three)
    assert np.array_equal(uniform_times(scene, 1.9, 2.0), [1.9, 2.0])


def test_instances_added_to_a_bound_are_rows_of_the_window_on_the_curve():
    # `instances x.bounds add T` imposes both bounds on the curve's value at T, beside the rows
    # on the control points (mutants: the added times looked up under another name, or cut at
    # no end, so that no row is made)
    s = run_lines(Session(), "time 0 1 knots=10\ndof x lo=-1 hi=1\ninstances x.bounds add 0.37\ninstances x.bounds add 0.8\n")
    groups = {g.label: g for g in WindowProblem(s.scene).groups}
    for side in ("lo", "hi"):
        assert np.allclose(groups[f"x.{side}+"].times, [0.37, 0.8])
        assert groups[f"x.{side}"].n == s.scene.dofs["x"].curve.n_coef


def test_merging_two_times_that_are_one_instance_keeps_one():
    # two times 1e-12 apart on a span of 1 are one instance (closer than 1e-9 of the span), also
    # when they are the only two (mutant: a pair returned as it came)
    assert np.array_equal(merge_times(np.array([0.5]), np.array([0.5 + 1e-12]), 1.0), [0.5])
    assert np.array_equal(merge_times(np.array([0.5]), np.array([0.25]), 1.0), [0.25, 0.5])
    assert np.array_equal(merge_times(np.array([0.5, 0.75]), np.array([0.5]), 1.0), [0.5, 0.75])
    # the same distance is relative to the span: 1e-9 s apart is one instance of a 10 s animation
    # (under 1e-8 s) and two of a 0.1 s one (over 1e-10 s) (mutant: the span divided, not multiplied)
    assert merge_times(np.array([0.05]), np.array([0.05 + 1e-9]), 10.0).size == 1
    assert merge_times(np.array([0.05]), np.array([0.05 + 1e-9]), 0.1).size == 2


def test_a_condition_that_is_constant_holds_everywhere_or_nowhere():
    # No condition, a literal true, a literal false: n booleans each, without evaluating a curve
    # (mutants: `None or true` read as `and`, the n dropped, the filler dropped for false)
    scene = run_lines(Session(), "time 0 2 knots=4\ndof x = t\n").scene
    times = np.linspace(0.0, 2.0, 8)   # not t = 1, where x > 1 is a tie
    for when, expected in ((None, True), (sp.true, True), (sp.false, False)):
        held = condition_holds(scene, when, times)
        assert held.dtype == bool and held.shape == (8,) and np.all(held == expected), when
    x = sp.Symbol("x", real=True)
    assert np.array_equal(condition_holds(scene, sp.Gt(x, 1), times), times > 1)


@pytest.mark.parametrize("r", [0, 1, 2])
@pytest.mark.parametrize("breaks", [[0.0, 1.0], [0.0, 0.4, 1.0], [0.0, 0.25, 0.5, 1.0], [0.0, 0.1, 0.3, 0.35, 0.8, 1.0]])
def test_exact_instances_determine_the_piecewise_polynomial(breaks, r):
    # A relation of degree 3 - r in time, C^(2 - r) at the knots, holds everywhere if it holds at
    # exact_times: as many points as the space's dimension (pieces + 3 - r), all in [a, b], at
    # which the space's collocation matrix is nonsingular (Schoenberg-Whitney). Built here with
    # scipy's B-splines of degree 3 - r on simple interior knots, not with stw's code. (mutants:
    # an interior point past the end of a single piece, two points made one, the single piece
    # taken for several)
    k = 3 - r
    breaks = np.array(breaks)
    times = exact_times(breaks, breaks[0], breaks[-1], r)
    assert np.all((times >= breaks[0]) & (times <= breaks[-1])) and np.all(np.diff(times) > 0)
    knots = np.r_[[breaks[0]] * k, breaks, [breaks[-1]] * k]
    collocation = BSpline.design_matrix(times, knots, k).toarray()
    assert collocation.shape == (breaks.size - 1 + k,) * 2
    assert np.linalg.cond(collocation) < 1e3


def test_added_instances_lie_on_the_animations_lattice_from_its_start():
    # _snap rounds to the nearest multiple of 1/SNAP of the animation counted from t0, inside it
    # (mutants: the length or the offset read with t0 added, which t0 = 0 hides)
    scene = SimpleNamespace(t0=1.0, t1=3.0)
    step = 2.0 / SNAP
    for k in (0, 1, 3, 12345):   # on the lattice: itself (mutant: a lattice twice as coarse)
        assert _snap(scene, 1.0 + k * step) == 1.0 + k * step
    for t in (1.0, 1.3, 2.0 + step / 3, 2.9999999, 3.0):
        snapped = _snap(scene, t)
        assert abs(snapped - t) <= step / 2 + 1e-15
        assert abs((snapped - 1.0) / step - round((snapped - 1.0) / step)) < 1e-6
        assert 1.0 <= snapped <= 3.0
    assert _snap(scene, 0.5) == 1.0 and _snap(scene, 3.5) == 3.0


def test_a_checks_json_and_the_failures_line_name_what_failed():
    # what `stw run --json` and `iterate`'s dense line read (mutants: the dense_tol key renamed,
    # given always or never; the list's separator, count and "and N more" tail)
    assert ConstraintCheck("c", 0.1, 0.2, 0.5, tol=0.3).as_dict() == \
        {"instances": 0.1, "dense": 0.2, "worst_t": 0.5, "dense_tol": 0.3}
    assert ConstraintCheck("c", 0.1, 0.2, 0.5).as_dict() == {"instances": 0.1, "dense": 0.2, "worst_t": 0.5}
    checks = {n: ConstraintCheck(n, 0.0, d, t, tol) for n, d, t, tol in
              (("a", 0.5, 0.25, None), ("b", 2.0, 1.5, 0.1), ("c", 1e-9, 0.5, None), ("d", 1.0, 0.75, None),
               ("e", 0.02, 1.0, 0.01))}
    report = DenseReport(checks)
    assert report.describe_failures(0.01) == \
        "b 2.0e+00 at t=1.5 (its dense_tol 0.1), d 1.0e+00 at t=0.75, a 5.0e-01 at t=0.25 and 1 more"
    assert report.describe_failures(0.01, limit=4) == \
        "b 2.0e+00 at t=1.5 (its dense_tol 0.1), d 1.0e+00 at t=0.75, a 5.0e-01 at t=0.25, e 2.0e-02 at t=1 (its dense_tol 0.01)"


@pytest.mark.parametrize("r", [0, 1])
def test_a_repeated_knot_frees_the_pieces_beside_it_and_its_midpoints_pin_them(r):
    # A double knot lowers the continuity there by one, which adds one dimension to the space;
    # the midpoints of the pieces on either side are added (one more than needed), at a double
    # knot anywhere inside, the first and last included, and at none at the interval's ends. The
    # points still determine the space: full column rank of its collocation matrix (scipy's
    # B-splines on the knots with the double one). A cubic with every inside knot double has
    # 10 dimensions, and the midpoints alone gave 9 points (this test found it: the relation
    # then held at its instances without holding everywhere). (mutants: the first or the last
    # inside knot skipped, an end taken, the wrong neighbours' midpoints)
    k = 3 - r
    breaks = np.array([0.0, 0.2, 0.45, 0.7, 1.0])
    ends = [0.1, 0.85] if r == 0 else [0.1]          # the docstring's: midpoints of the first and last piece
    for double in ([0.2], [0.7], [0.2, 0.45, 0.7]):
        times = exact_times(breaks, 0.0, 1.0, r, np.array(double + [0.0, 1.0]))   # the ends: nothing
        beside = [(breaks[i - 1] + breaks[i]) / 2 for i in range(1, breaks.size)
                  if breaks[i] in double or breaks[i - 1] in double]
        documented = np.unique(np.r_[breaks, ends, beside])
        inner = np.sort(np.r_[breaks[1:-1], double])
        knots = np.r_[[0.0] * (k + 1), inner, [1.0] * (k + 1)]
        dimension = knots.size - k - 1
        if documented.size >= dimension:   # those points, and no others
            np.testing.assert_allclose(times, documented, rtol=0, atol=1e-15)
        else:   # shared midpoints (every piece of a cubic beside a double knot): more are added
            assert all(np.isclose(times, p).any() for p in documented)
        collocation = BSpline.design_matrix(times, knots, k).toarray()
        assert np.linalg.matrix_rank(collocation) == dimension


def test_added_instances_are_those_inside_the_interval_ends_included():
    # (mutants: or for and, an end left out)
    scene = SimpleNamespace(extra_instances={"c": [0.1, 0.5, 0.75, 1.0, 1.5]})
    assert np.array_equal(extra_times(scene, "c", 0.5, 1.0), [0.5, 0.75, 1.0])
    none = extra_times(scene, "other", 0.0, 2.0)
    assert none.size == 0 and none.dtype == float


def test_a_broken_bound_asks_for_no_refinement():
    # A bound's rows are its control points, which keep the curve inside it everywhere once they
    # hold: adaptive refinement adds no instances for it however far a control point is past it,
    # and reports no failing peaks to insert knots at; a relation on the same curve, sampled at
    # instances, does get them. (mutants: the bound's samples marked not exact)
    s = run_lines(Session(), "time 0 1 knots=10\ndof x lo=-1 hi=1\nconstraint low: x <= 0.5 on [0, 1] samples=4\n")
    dof = s.scene.dofs["x"]
    dof.curve = dof.curve.with_coef(1.5 * np.sin(np.linspace(0.0, 3 * np.pi, dof.curve.n_coef)))
    report, wanted, failing = survey_failures(s.scene, 1e-3)
    assert report.checks["x.bounds"].dense > 0.3
    assert "x.bounds" not in wanted and "x.bounds" not in failing
    assert wanted["low"].size and failing["low"].shape[0]


def test_a_breakpoint_within_rounding_of_an_end_is_that_end():
    # "Within rounding" is 1e-9 of the interval's length, or of 1 s when it is shorter: a knot
    # half of that inside an end is the end, one twice that is a piece of its own. (mutants: the
    # length divided, read as b + a, or its floor made 2)
    for a, b in ((0.0, 1.0), (0.0, 4.0), (3.0, 4.0), (0.0, 0.25)):
        slack = 1e-9 * max(b - a, 1.0)
        near = np.array([a, a + 0.5 * slack, (a + b) / 2, b - 0.5 * slack, b])
        assert np.array_equal(interval_cuts(near, a, b), [a, (a + b) / 2, b]), (a, b)
        far = np.array([a, a + 2 * slack, b - 2 * slack, b])
        assert np.array_equal(interval_cuts(far, a, b), [a, a + 2 * slack, b - 2 * slack, b]), (a, b)


def test_a_relations_dof_are_those_it_reads_where_it_holds():
    # Inside the hold the ball is the hand (the shoulder's curve); after the release, its own.
    # (mutants: the scope dropped, every DOF taken)
    s = run_lines(Session(), HELD)
    bx = dof_symbol("BX")
    assert dofs_used(s.scene, [bx], (0.3, 0.7)) == ["SHOULDER"]
    assert dofs_used(s.scene, [bx], (0.75, 1.0)) == ["BX"]
    # over the whole animation, both: the hand while held, the ball's curve outside
    assert dofs_used(s.scene, [dof_symbol("BY", 2) + 1], None) == ["SHOULDER", "BY"]


def test_an_exact_relation_after_a_release_asks_for_no_refinement():
    # BX'' = 0 after the release is affine in the ball's own curve: its instances make it exact,
    # and adaptive refinement adds none however far the curve breaks it between them (mutant:
    # exactness decided without the relation's scope, where the hold's hand makes it curved).
    s = run_lines(Session(), HELD + "dof BX = sin(20*t)\nconstraint fly: BX'' = 0 on [0.75, 1]\n")
    report, wanted, failing = survey_failures(s.scene, 1e-3)
    assert report.checks["fly"].dense > 1.0
    assert "fly" not in wanted and "fly" not in failing


def test_a_relation_on_a_released_object_is_exact_on_its_own_curve():
    # After the release the ball is its own cubic curve: BX'' = 0 there is affine in it (exact
    # instances, r = 2); inside the hold it is the hand, trigonometry of the shoulder (no finite
    # set of instances makes it exact). (mutant: the relation read without its scope, both
    # branches of the hold at once, so never exact)
    s = run_lines(Session(), HELD)
    assert exact_degree(s.scene, dof_symbol("BX", 2), TermKind.EQ, (0.75, 1.0)) == 2
    assert exact_degree(s.scene, dof_symbol("BX", 2), TermKind.EQ, (0.25, 0.75)) is None


def test_a_repeated_knot_within_rounding_of_an_end_is_that_end():
    # "Within rounding" is 1e-9 of the larger of |a|, |b| and 1: a double knot that close to b
    # sends the instances at b just before the knot (the interval's own side); one farther away
    # is inside and moves nothing. (mutants: the scale divided, or read from one end only, or
    # its floor dropped or made 2) No knots at all: nothing repeated (mutant: concatenate of none).
    for a, b in ((0.0, 4.0), (-4.0, 1.0), (0.0, 0.5), (-0.25, 0.25)):
        slack = 1e-9 * max(abs(a), abs(b), 1.0)
        times = np.linspace(a, b, 5)
        moved = on_own_side(times, a, b, np.array([b - 0.75 * slack]))
        assert moved[-1] == np.nextafter(b - 0.75 * slack, -np.inf) and np.array_equal(moved[:-1], times[:-1]), (a, b)
        assert np.array_equal(on_own_side(times, a, b, np.array([b - 1.5 * slack])), times), (a, b)
        started = on_own_side(times, a, b, np.array([a + 0.75 * slack]))
        assert started[0] == a + 0.75 * slack and np.array_equal(started[1:], times[1:]), (a, b)
    assert repeated_knots([]).size == 0


def test_refinement_asks_for_an_instance_at_each_interior_peak_over_the_limit_only():
    # x <= 0 on [0, 2] at instances 0, 0.5, 1, 1.5, 2, with a bump of 0.5 at 0.75, one of 0.05 at
    # 1.25 (under the limit 0.1) and a rise 0.5 (t/2)^8 to the end t = 2 (an instance already):
    # refinement wants one instance, at 0.75; the failing peaks are 0.75 and the end. With the
    # two ends as its only instances the relation is refined too. (mutants: points above the
    # limit or falling points counted as peaks, rising ones, a relation of two instances skipped)
    def scene(samples, end="0.5*(t/2)^8"):
        return run_lines(Session(), f"""time 0 2 knots=60
dof x = 0.5*exp(-((t - 0.75)/0.08)^2) + 0.05*exp(-((t - 1.25)/0.08)^2) + {end}
constraint c: x <= 0 on [0, 2] samples={samples}
""").scene
    _, wanted, failing = survey_failures(scene(4), 0.1)
    np.testing.assert_allclose(wanted["c"], [0.75], atol=2e-3)
    # the peaks' rows, on the grid and its zoom (1/8 of a knot span, then finer): at 0.75 and 2 only
    t, v = failing["c"][:, 0], failing["c"][:, 1]
    near = np.minimum(np.abs(t - 0.75), np.abs(t - 2.0))
    assert near.max() < 5e-3 and (np.abs(t - 0.75) < 5e-3).any() and (t == 2.0).any()
    np.testing.assert_allclose(v, 0.5, atol=0.01)
    # (one gap: its worst peak decides, and the rise to t = 2 would be it, at an instance already)
    _, wanted, failing = survey_failures(scene(1, end="0"), 0.1)
    np.testing.assert_allclose(wanted["c"], [0.75], atol=2e-3)
    assert np.abs(failing["c"][:, 0] - 0.75).max() < 5e-3


def test_each_relation_of_a_constraint_is_refined_after_an_exact_one():
    # `y = 0` is exact (affine in y: nothing to refine), `x <= 0` after it is not: a violation
    # falling from 0.5 at t = 0 (a failing peak at the first grid point, an instance already),
    # and a bump of 0.5 at 0.77 (between instances) that refinement asks for an instance at.
    # (mutants: the relations after an exact one skipped; the first grid point never a peak)
    s = run_lines(Session(), """time 0 2 knots=60
dof y = t
dof x = 0.5*exp(-((t - 0.77)/0.08)^2) + 0.5*(1 - t/2)^8
constraint c: y = 0, x <= 0 on [0, 2]
""")
    _, wanted, failing = survey_failures(s.scene, 0.1)
    assert (np.abs(wanted["c"] - 0.77) < 5e-3).any()    # (the ramp's gaps too, between instances)
    t = failing["c"][:, 0]
    assert (t == 0.0).any() and (np.abs(t - 0.77) < 5e-3).any()


def test_added_instances_merge_relative_to_the_animations_length_from_t0():
    # On [1, 3] (2 s) two instances 3e-9 s apart are two (over 1e-9 x 2 s). (mutant: the
    # length read as t1 + t0 = 4 s, which merges them)
    s = run_lines(Session(), """time 1 3 knots=8
dof x
constraint c: x*x <= 1 on [1, 3] samples=4
instances c add 1.500000003
""")
    c = s.scene.constraints["c"]
    times = relation_times(s.scene, c, c.relations[0].expr, c.relations[0].kind)
    assert np.isclose(times, 1.5, rtol=0, atol=1e-12).any() and np.isclose(times, 1.500000003, rtol=0, atol=1e-12).any()
