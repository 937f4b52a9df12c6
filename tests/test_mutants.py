"""Tests that kill mutants mutmut found surviving in stw_tui/sos/ and stw_tui/sym/linkage/ (issue 56).

Each asserts real behaviour derived apart from the code under test (README, "Contributing:
mutation testing").
"""

from types import SimpleNamespace

import numpy as np

from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.sos.instances import merge_times, uniform_times
from stw_tui.sos.window import WindowProblem


def test_uniform_samples_keep_the_scene_density_on_an_interval_away_from_zero():
    # 8 samples over an animation of 2 s is 4 per second, wherever the interval lies: [1, 2]
    # and [0.5, 1.5] get 4 steps each, [1.5, 2] two; samples=6 (per animation) gives [1, 2] 3.
    # (mutant: the interval's length read as b + a, 12 steps on [1, 2])
    scene = SimpleNamespace(t0=0.0, t1=2.0, sample_count=8)
    assert np.array_equal(uniform_times(scene, 1.0, 2.0), np.linspace(1.0, 2.0, 5))
    assert np.array_equal(uniform_times(scene, 0.5, 1.5), np.linspace(0.5, 1.5, 5))
    assert np.array_equal(uniform_times(scene, 1.5, 2.0), np.linspace(1.5, 2.0, 3))
    assert np.array_equal(uniform_times(scene, 1.0, 2.0, samples=6), np.linspace(1.0, 2.0, 4))


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
