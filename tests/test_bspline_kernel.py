"""bspline_kernel: de Boor in numpy gives scipy.interpolate's numbers, to the last bit.

The oracle is scipy itself (BSpline, its design matrix and make_lsq_spline's normal equations),
on random clamped knot vectors with uneven and repeated interior knots, at random times, at the
knots themselves and at both ends.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.interpolate import BSpline, make_lsq_spline

from stw_tui.sos import bspline_kernel
from stw_tui.sos.spline import DofCurve, gauss_legendre_nodes


def random_knots(rng: np.random.Generator, degree: int) -> np.ndarray:
    t0 = rng.uniform(-2.0, 2.0)
    t1 = t0 + rng.uniform(0.1, 5.0)
    inner = np.sort(rng.uniform(t0, t1, int(rng.integers(0, 12))))
    if inner.size > 2:                                   # a knot of multiplicity up to degree + 1
        inner = np.sort(np.r_[inner, np.repeat(inner[rng.integers(0, inner.size)], rng.integers(1, degree + 1))])
    return np.r_[[t0] * (degree + 1), inner, [t1] * (degree + 1)]


def random_times(rng: np.random.Generator, knots: np.ndarray) -> np.ndarray:
    inside = rng.uniform(knots[0], knots[-1], int(rng.integers(1, 60)))
    return np.sort(np.r_[inside, knots[rng.integers(0, knots.size, 5)], knots[0], knots[-1]])


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_spline_values_equal_bsplines_bit_for_bit(degree):
    rng = np.random.default_rng(degree)
    for _ in range(200):
        knots = random_knots(rng, degree)
        times = random_times(rng, knots)
        coef = rng.standard_normal(knots.size - degree - 1)
        for nu in range(degree + 1):
            expected = BSpline(knots, coef, degree)(times, nu=nu)
            assert np.array_equal(bspline_kernel.spline_values(knots, coef, times, degree, nu), expected)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_design_matrix_equals_scipys_entry_for_entry(degree):
    rng = np.random.default_rng(10 + degree)
    for _ in range(200):
        knots = random_knots(rng, degree)
        times = random_times(rng, knots)
        expected = BSpline.design_matrix(times, knots, degree)
        got = bspline_kernel.design_matrix(times, knots, degree)
        assert got.shape == expected.shape
        for part in ("data", "indices", "indptr"):
            assert np.array_equal(getattr(got, part), getattr(expected, part))
            assert getattr(got, part).dtype == getattr(expected, part).dtype


def test_least_squares_equals_make_lsq_splines_normal_equations_and_is_near_its_qr():
    """Bit for bit against method="norm-eq", and within 1e-13 relative of the QR default."""
    rng = np.random.default_rng(7)
    for _ in range(100):
        spans = int(rng.integers(1, 40))
        t0 = rng.uniform(-1.0, 1.0)
        t1 = t0 + rng.uniform(0.2, 5.0)
        inner = np.sort(rng.uniform(t0, t1, spans - 1)) if rng.random() < 0.5 else np.linspace(t0, t1, spans + 1)[1:-1]
        knots = np.r_[[t0] * 4, inner, [t1] * 4]
        times, weights = gauss_legendre_nodes(np.unique(knots), 6, t0, t1)
        values = np.sin(3 * times) + 0.1 * rng.standard_normal(times.size)
        w = np.sqrt(weights)
        got = bspline_kernel.least_squares(times, values, knots, 3, w)
        assert np.array_equal(got, make_lsq_spline(times, values, knots, 3, w=w, method="norm-eq").c)
        qr = make_lsq_spline(times, values, knots, 3, w=w).c
        assert np.max(np.abs(got - qr)) <= 1e-13 * np.max(np.abs(qr))


def test_fitting_a_constant_gives_that_constant_exactly():
    """A pose a session states (dof SHOULDER = -pi/2) is kept to the last bit, not within the
    ~1e-15 noise a least-squares solve leaves."""
    curve = DofCurve.fit(0.0, 1.5, 24, lambda t: np.full_like(t, -np.pi / 2))
    assert np.all(curve.coef == -np.pi / 2)


def test_a_replay_that_fits_refines_and_evaluates_curves_does_not_import_scipy_interpolate():
    """scipy.interpolate pulls scipy.optimize, special, spatial and fft in: 0.3 s of `stw run`."""
    script = ("import sys\n"
              "from stw_tui.session.session import Session\n"
              "s = Session()\n"
              "s.run_text('time 0 1 knots=8\\ndof X = sin(t)\\ndof Y = 0.5\\nprint X + Y on [0.2, 0.4]\\n'\n"
              "           'refine X [0.2, 0.5]\\nrefine Y @ 0.3 multiplicity=2\\nprint X @ 0.35\\n')\n"
              "print(sorted(m for m in ('scipy.interpolate', 'scipy.optimize') if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert done.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize("seed", range(4))
def test_knot_insertion_equals_scipys_insert_bit_for_bit(seed):
    """Boehm insertion as FITPACK's fpinst does it: new knots and coefficients equal
    scipy.interpolate.insert's exactly, at new places and at existing knots, up to three times."""
    from scipy.interpolate import insert

    rng = np.random.default_rng(100 + seed)
    at_knots = 0
    for _ in range(500):
        knots = random_knots(rng, 3)
        coef = rng.standard_normal(knots.size - 4)
        inner = knots[4:-4]
        if inner.size and rng.random() < 0.3:
            x, at_knots = float(inner[rng.integers(0, inner.size)]), at_knots + 1
        else:
            x = float(rng.uniform(knots[0], knots[-1]))
        times = int(rng.integers(1, 4))
        want = insert(x, BSpline(knots, coef, 3), m=times)
        got_knots, got_coef = bspline_kernel.insert_knot(knots, coef, x, 3, times)
        assert np.array_equal(got_knots, want.t)
        assert np.array_equal(got_coef, want.c[:want.t.size - 4])   # FITPACK pads c to len(t)
    assert at_knots > 100


def test_knot_insertion_keeps_the_curve_and_refuses_the_ends():
    rng = np.random.default_rng(7)
    knots = np.r_[[0.0] * 4, np.sort(rng.uniform(0, 2, 6)), [2.0] * 4]
    coef = rng.standard_normal(knots.size - 4)
    times = np.linspace(0, 2, 101)
    new_knots, new_coef = bspline_kernel.insert_knot(knots, coef, 0.7, 3, 2)
    assert new_knots.size == knots.size + 2 and np.count_nonzero(new_knots == 0.7) == 2
    np.testing.assert_allclose(bspline_kernel.spline_values(new_knots, new_coef, times, 3),
                               bspline_kernel.spline_values(knots, coef, times, 3), rtol=0, atol=1e-13)
    for end in (0.0, 2.0, -1.0):
        with pytest.raises(ValueError, match="inside the spline's span"):
            bspline_kernel.insert_knot(knots, coef, end, 3)
