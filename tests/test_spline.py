"""DofCurve: sparse bases vs scipy's BSpline, fitting, Boehm refinement, user tools, quadrature."""

import numpy as np
import pytest
import scipy.sparse as sps
from scipy.interpolate import BSpline, CubicSpline

from stw_tui.sos.spline import DofCurve, clamped_uniform_knots, gauss_legendre_nodes


def random_curve(seed=0, spans=7, t0=-0.5, t1=2.0):
    rng = np.random.default_rng(seed)
    return DofCurve.uniform(t0, t1, spans).shaken(1.0, rng)


def bending(curve):
    """∫ X''² dt, exact with 2 Gauss points a span (X'' is piecewise linear)."""
    t, w = gauss_legendre_nodes(curve.breakpoints, 2, curve.t0, curve.t1)
    return float(w @ curve.evaluate(t, 2) ** 2)


def _bending_of(spline, a, b):
    t, w = gauss_legendre_nodes(spline.x, 2, a, b)
    return float(w @ spline(t, 2) ** 2)


# --- construction and properties -----------------------------------------------------------
def test_uniform_properties():
    c = DofCurve.uniform(0.0, 2.0, 4, value=1.5)
    assert c.degree == 3 and c.t0 == 0.0 and c.t1 == 2.0
    assert c.spans == 4 and c.n_coef == 7 and len(c.knots) == 11
    np.testing.assert_array_equal(c.breakpoints, [0, 0.5, 1, 1.5, 2])
    assert c.span_width() == pytest.approx(0.5, abs=1e-15)
    np.testing.assert_allclose(c.evaluate(np.linspace(0, 2, 9)), 1.5, atol=1e-14)
    sup = c.support()
    assert sup.shape == (7, 2)
    np.testing.assert_array_equal(sup[0], [0, 0.5])
    np.testing.assert_array_equal(sup[3], [0, 2])
    np.testing.assert_array_equal(sup[-1], [1.5, 2])


def test_immutable_and_validated():
    c = random_curve()
    with pytest.raises(ValueError):
        c.coef[0] = 1.0
    with pytest.raises(ValueError):
        c.with_coef(np.zeros(c.n_coef + 1))
    with pytest.raises(ValueError):  # not clamped
        DofCurve(np.linspace(0, 1, 10), np.zeros(6))
    with pytest.raises(ValueError):
        DofCurve.uniform(0, 1, 0)
    src = np.arange(c.n_coef, dtype=float)
    d = c.with_coef(src)
    src[0] = 99.0  # the curve keeps its own copy
    assert d.coef[0] == 0.0
    assert not d.coef.flags.writeable and d.knots is c.knots   # checked knots shared, not checked again
    with pytest.raises(ValueError):
        c.with_coef(np.zeros((c.n_coef, 1)))


# --- bases ---------------------------------------------------------------------------------
@pytest.mark.parametrize("order", [0, 1, 2])
@pytest.mark.parametrize("refine", [False, True])
def test_basis_matches_bspline(order, refine):
    c = random_curve(seed=order, spans=9)
    if refine:  # non-uniform knots too
        c = c.refined(0.1, 0.6).refined(0.15, 0.2, factor=3)
    rng = np.random.default_rng(42)
    times = np.concatenate([[c.t0, c.t1], rng.uniform(c.t0, c.t1, 300), c.breakpoints])
    M = c.basis(times, order)
    assert sps.issparse(M) and M.shape == (times.size, c.n_coef)
    assert np.diff(M.indptr).max() <= 4
    expected = BSpline(c.knots, c.coef, 3)(times, nu=order)
    tol = 1e-12 * max(1, np.abs(expected).max())  # derivatives scale like 1/h^order
    np.testing.assert_allclose(M @ c.coef, expected, rtol=0, atol=tol)
    np.testing.assert_allclose(c.evaluate(times, order), expected, rtol=0, atol=tol)


def test_basis_right_end_and_range_checks():
    c = random_curve()
    np.testing.assert_allclose(c.basis([c.t1]) @ c.coef, [c.coef[-1]], atol=1e-15)
    np.testing.assert_allclose(c.basis([c.t0]) @ c.coef, [c.coef[0]], atol=1e-15)
    for bad in ([c.t1 + 1e-6], [c.t0 - 1e-6], [np.nan]):
        with pytest.raises(ValueError):
            c.basis(bad)
        with pytest.raises(ValueError):
            c.evaluate(bad)
    with pytest.raises(ValueError):
        c.basis([0.0], order=3)
    assert c.basis(np.zeros(0), 1).shape == (0, c.n_coef)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_basis_rejects_any_time_outside_interval(order):
    c = random_curve(seed=1).refined(0.0, 1.0)
    good = np.linspace(c.t0, c.t1, 11)
    for bad in (c.t0 - 1e-9, c.t1 + 1e-9, c.t1 + 10.0, -np.inf, np.nan):
        with pytest.raises(ValueError):
            c.basis(np.append(good, bad), order)  # one bad entry among good ones is enough
    # Rounding noise (1e-13 past an end) is accepted and clamped to the end.
    edge = c.basis([c.t0 - 1e-13, c.t1 + 1e-13], order).toarray()
    np.testing.assert_array_equal(edge, c.basis([c.t0, c.t1], order).toarray())


@pytest.mark.parametrize("refine", [False, True])
def test_support_matches_nonzero_basis(refine):
    c = random_curve(seed=2, spans=6, t0=0.0, t1=6.0)
    if refine:
        c = c.refined(1.2, 2.1, factor=3).refined(4.0, 4.4)
    sup = c.support()
    assert sup.shape == (c.n_coef, 2) and np.all(sup[:, 1] > sup[:, 0])
    t = np.concatenate([np.random.default_rng(3).uniform(c.t0, c.t1, 2000), c.breakpoints])
    B = c.basis(t).toarray()
    lo, hi = sup[:, 0][None, :], sup[:, 1][None, :]
    inside = (t[:, None] > lo) & (t[:, None] < hi)
    outside = (t[:, None] < lo) | (t[:, None] > hi)
    assert np.all(B[inside] > 0)  # B-splines are positive on the open support ...
    assert np.all(B[outside] == 0)  # ... and exactly zero off the closed one
    np.testing.assert_allclose(B.sum(axis=1), 1.0, rtol=0, atol=1e-14)  # partition of unity
    # Every nonzero sits in its column's closed support.
    rows, cols = np.nonzero(B)
    assert np.all((t[rows] >= sup[cols, 0]) & (t[rows] <= sup[cols, 1]))


# --- fitting -------------------------------------------------------------------------------
def test_fit_reproduces_cubic():
    p = np.polynomial.Polynomial([0.3, -1.0, 2.0, 0.7])
    c = DofCurve.fit(-1.0, 2.0, 5, p)
    t = np.linspace(-1, 2, 201)
    for order in range(3):
        np.testing.assert_allclose(c.evaluate(t, order), p.deriv(order)(t), rtol=0, atol=1e-12)


def test_fit_sin_and_refit():
    c = DofCurve.fit(0.0, 2 * np.pi, 20, np.sin)
    t = np.linspace(0, 2 * np.pi, 1001)
    # cubic spline error ~ h^4 |f''''| / 384 with h = 0.31: ~3e-5
    assert np.abs(c.evaluate(t) - np.sin(t)).max() < 1e-4
    r = c.refined(1.0, 2.0).refit(np.cos)
    assert np.array_equal(r.knots, c.refined(1.0, 2.0).knots)
    assert np.abs(r.evaluate(t) - np.cos(t)).max() < 1e-4
    const = c.refit(lambda t: 2.0)  # a scalar result broadcasts
    np.testing.assert_allclose(const.coef, 2.0, atol=1e-12)


# --- refinement ----------------------------------------------------------------------------
def test_refined_keeps_curve_and_splits_only_overlapping_spans():
    c = random_curve(seed=3, spans=8, t0=0.0, t1=8.0)  # breakpoints at integers
    r = c.refined(2.5, 4.2)  # overlaps spans [2,3], [3,4], [4,5]
    np.testing.assert_array_equal(np.setdiff1d(r.breakpoints, c.breakpoints), [2.5, 3.5, 4.5])
    assert len(r.knots) == len(c.knots) + 3 and r.n_coef == c.n_coef + 3
    assert r.spans == 11
    t = np.random.default_rng(1).uniform(0, 8, 500)
    for order in range(3):
        np.testing.assert_allclose(r.evaluate(t, order), c.evaluate(t, order), rtol=0, atol=1e-12)
    r3 = c.refined(0.0, 1.0, factor=3)  # touches only [0, 1]; (a, b) is open
    np.testing.assert_allclose(np.setdiff1d(r3.breakpoints, c.breakpoints), [1 / 3, 2 / 3], atol=1e-15)
    np.testing.assert_allclose(r3.evaluate(t), c.evaluate(t), rtol=0, atol=1e-12)
    assert r3.span_width() == 1.0 and r3.refined(0, 8).span_width() == 0.5
    with pytest.raises(ValueError):
        c.refined(1.0, 2.0, factor=1)


@pytest.mark.parametrize("a, b, factor", [
    (2.5, 4.2, 2),  # ends inside spans: 3 spans overlap
    (3.0, 5.0, 2),  # ends on breakpoints: (a, b) is open, so just [3,4], [4,5]
    (0.1, 0.2, 4),  # inside one span
    (-1.0, 0.5, 3),  # a before t0
    (7.9, 9.0, 2),  # b after t1
    (4.0, 4.0, 2),  # empty interval on a breakpoint: nothing overlaps
])
def test_refined_growth_and_untouched_knots(a, b, factor):
    c = random_curve(seed=4, spans=8, t0=0.0, t1=8.0)
    bp = c.breakpoints
    hit = (bp[:-1] < b) & (bp[1:] > a)
    n_hit = int(hit.sum())
    r = c.refined(a, b, factor)
    assert r.n_coef == c.n_coef + (factor - 1) * n_hit
    assert r.spans == c.spans + (factor - 1) * n_hit
    # Every old knot (with multiplicity) is still there; new ones lie only in the split spans.
    old, counts = np.unique(c.knots, return_counts=True)
    new_vals, new_counts = np.unique(r.knots, return_counts=True)
    pos = np.searchsorted(new_vals, old)
    np.testing.assert_array_equal(new_vals[pos], old)
    np.testing.assert_array_equal(new_counts[pos], counts)
    added = np.setdiff1d(r.knots, c.knots)
    assert added.size == (factor - 1) * n_hit
    if n_hit:
        lo, hi = bp[:-1][hit].min(), bp[1:][hit].max()
        assert np.all((added > lo) & (added < hi))
        # Knots left of the first split span and right of the last one are untouched.
        np.testing.assert_array_equal(r.knots[r.knots <= lo], c.knots[c.knots <= lo])
        np.testing.assert_array_equal(r.knots[r.knots >= hi], c.knots[c.knots >= hi])
    else:
        np.testing.assert_array_equal(r.knots, c.knots)
    t = np.random.default_rng(6).uniform(0.0, 8.0, 500)
    for order in range(3):
        np.testing.assert_allclose(r.evaluate(t, order), c.evaluate(t, order), rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.basis(t, order) @ r.coef, c.evaluate(t, order), rtol=0, atol=1e-12)


# --- sketching -----------------------------------------------------------------------------
def test_sketch_no_keys_is_identity():
    c = random_curve()
    assert c.sketched([]) is c
    s = c.sketched(np.zeros((0, 2)))
    assert np.array_equal(s.knots, c.knots) and np.array_equal(s.coef, c.coef)


def test_sketch_single_key_is_local_with_anchor():
    """With an anchor (decay length (1e-3/1e-1)^0.25 ≈ 0.3) a key near one end leaves the other alone.

    With the default tiny anchor the change is a near-constant shift by design (see the docstring
    and the test below), so "far away changes little" only holds for a real anchor.
    """
    c = DofCurve.fit(0.0, 10.0, 40, np.sin)
    for key_t in (5.0, 1.5):
        s = c.sketched([(key_t, 2.0)], smoothness=1e-3, anchor=1e-1)
        at_key = abs(s.evaluate(key_t)[0] - c.evaluate(key_t)[0])
        assert at_key > 0.5  # the key pulled the curve a real distance (offset ~1.0-2.0)
        far = np.linspace(9.0, 10.0, 51)  # near the other end
        change_far = np.abs(s.evaluate(far) - c.evaluate(far)).max()
        assert change_far < 1e-3 * at_key


def test_sketch_meets_keys_and_is_smooth():
    c = DofCurve.fit(0.0, 8.0, 32, lambda t: 0.5 * np.sin(t))
    keys = [(2.0, 1.0), (4.0, -0.5), (6.0, 0.5)]
    s = c.sketched(keys)
    kt, kv = np.array(keys).T
    # The key residual is about smoothness x the jump of D''' at the key (smoothness has units
    # time³): keys 2 apart with offsets ~1 meet the default 1e-3 within 1e-3 ...
    assert np.abs(s.evaluate(kt) - kv).max() < 1e-3
    # ... and the residual vanishes with the smoothness weight.
    res = [np.abs(c.sketched(keys, sm).evaluate(kt) - kv).max() for sm in (1e-1, 1e-3, 1e-5, 1e-7)]
    assert res[0] > res[1] > res[2] > res[3] and res[3] < 1e-6
    # Minimal bending: D = s - c is close to the natural cubic spline through the key offsets
    # (keys lie on knots, so that spline is in the space), continued linearly beyond the keys.
    D = s.with_coef(s.coef - c.coef)
    natural = CubicSpline(kt, kv - c.evaluate(kt), bc_type="natural")
    t = np.linspace(0.0, 8.0, 801)
    inside = (t >= 2) & (t <= 6)
    np.testing.assert_allclose(D.evaluate(t[inside]), natural(t[inside]), rtol=0, atol=2e-3)
    for lo, hi, end in ((0.0, 2.0, 2.0), (6.0, 8.0, 6.0)):  # linear continuation outside the keys
        tt = t[(t >= lo) & (t <= hi)]
        line = natural(end) + natural(end, 1) * (tt - end)
        np.testing.assert_allclose(D.evaluate(tt), line, rtol=0, atol=5e-3)
    assert bending(D) < 1.01 * _bending_of(natural, 2, 6)


def test_sketch_single_key_shifts_and_anchor_localizes():
    c = DofCurve.fit(0.0, 10.0, 40, np.cos)
    t = np.linspace(0, 10, 401)
    # Default tiny anchor: minimal bending means a near-constant shift of the whole curve.
    s = c.sketched([(5.0, 3.0)])
    shift = 3.0 - np.cos(5.0)
    assert abs(s.evaluate(5.0)[0] - 3.0) < 1e-3
    np.testing.assert_allclose(s.evaluate(t) - c.evaluate(t), shift, rtol=1e-3)
    # A larger anchor keeps far parts near the current curve: decay length (1e-3/1e-1)^0.25 ≈ 0.3.
    local = c.sketched([(5.0, 3.0)], smoothness=1e-3, anchor=1e-1)
    change = np.abs(local.evaluate(t) - c.evaluate(t))
    assert abs(local.evaluate(5.0)[0] - 3.0) < 0.2 * abs(shift)
    assert change[np.abs(t - 5.0) > 4.0].max() < 1e-3 * abs(shift)
    with pytest.raises(ValueError):
        c.sketched([(11.0, 0.0)])


# --- filter and shake ----------------------------------------------------------------------
def test_filter_smooths_and_keeps_ends():
    rng = np.random.default_rng(5)
    smooth = DofCurve.fit(0.0, 3.0, 30, lambda t: t ** 2)
    noisy = smooth.shaken(0.2, rng)
    f1, f5 = noisy.filtered(), noisy.filtered(5)
    assert bending(f1) < 0.5 * bending(noisy) and bending(f5) < bending(f1)
    tv = lambda c: np.abs(np.diff(c.coef)).sum()
    assert tv(f1) < tv(noisy)
    rough = lambda c: float(np.sum(np.diff(c.coef, 2) ** 2))
    assert rough(f1) < 0.5 * rough(noisy) and rough(f5) < rough(f1)
    for f in (f1, f5):  # end control points kept exactly
        assert f.coef[0] == noisy.coef[0] and f.coef[-1] == noisy.coef[-1]
    for f in (f1, f5):
        np.testing.assert_allclose(f.evaluate([0.0, 3.0]), noisy.evaluate([0.0, 3.0]), rtol=0, atol=1e-14)
    # The interior stencil, explicitly.
    c = noisy.coef
    np.testing.assert_allclose(f1.coef[1:-1], (c[:-2] + 2 * c[1:-1] + c[2:]) / 4, atol=1e-15)
    assert noisy.filtered(0).coef.tolist() == noisy.coef.tolist()
    # A line's control points sit at the Greville abscissae, equally spaced away from the clamped
    # ends: there the filter leaves it alone (near the ends it bends it slightly).
    line = DofCurve.fit(0.0, 3.0, 10, lambda t: 2 * t - 1)
    np.testing.assert_allclose(line.filtered(3).coef[6:-6], line.coef[6:-6], atol=1e-12)


def test_shake_seeded():
    c = random_curve()
    a = c.shaken(0.1, np.random.default_rng(7))
    b = c.shaken(0.1, np.random.default_rng(7))
    d = c.shaken(0.1, np.random.default_rng(8))
    big = c.shaken(0.3, np.random.default_rng(7))
    assert np.array_equal(a.coef, b.coef)
    assert not np.allclose(a.coef, d.coef)
    np.testing.assert_allclose(big.coef - c.coef, 3 * (a.coef - c.coef), rtol=1e-12, atol=1e-15)
    assert c.shaken(0.0, np.random.default_rng(1)).coef.tolist() == c.coef.tolist()


@pytest.mark.parametrize("amplitude", [1e-3, 0.5, 20.0])
def test_shake_amplitude_sets_std(amplitude):
    c = DofCurve.uniform(0.0, 1.0, 997, value=3.0)  # 1000 control points
    delta = c.shaken(amplitude, np.random.default_rng(11)).coef - c.coef
    # Sample std of 1000 N(0, a²) draws: relative error ~ 1/sqrt(2000) ≈ 2%; allow 10%.
    assert 0.9 * amplitude < delta.std() < 1.1 * amplitude
    assert abs(delta.mean()) < 0.15 * amplitude  # mean ~ a/sqrt(1000) ≈ 0.03 a


# --- quadrature ----------------------------------------------------------------------------
def test_gauss_legendre_piecewise_degree7_exact():
    bps = clamped_uniform_knots(0.0, 3.0, 3)  # breakpoints 0, 1, 2, 3 (with repeats)
    # A different degree-7 polynomial on each piece: discontinuous at 1 and 2.
    rng = np.random.default_rng(0)
    pieces = [np.polynomial.Polynomial(rng.normal(size=8)) for _ in range(3)]

    def f(t):
        return np.select([t < 1, t < 2, t >= 2], [p(t) for p in pieces])

    a, b = 0.4, 2.7
    t, w = gauss_legendre_nodes(bps, 4, a, b)
    assert t.size == 12 and np.all(np.diff(t) > 0) and t.min() > a and t.max() < b
    exact = sum(p.integ()(hi) - p.integ()(lo) for p, (lo, hi) in zip(pieces, [(a, 1), (1, 2), (2, b)]))
    assert abs(w @ f(t) - exact) < 1e-12 * max(1, abs(exact))
    # 3 points a span are not enough for degree 7 (the check above is not vacuous).
    t3, w3 = gauss_legendre_nodes(bps, 3, a, b)
    assert abs(w3 @ f(t3) - exact) > 1e-9
    assert gauss_legendre_nodes(bps, 4, 1.0, 1.0)[0].size == 0


@pytest.mark.parametrize("a, b", [(0.0, 3.0), (0.4, 2.7), (1.0, 2.0), (0.25, 0.75), (-1.3, 4.9), (2.2, 2.2001)])
@pytest.mark.parametrize("n", [1, 2, 4, 6])
def test_gauss_legendre_weights_sum_and_nodes(a, b, n):
    bps = np.array([0.0, 0.0, 1.0, 1.0, 2.0, 3.0, 3.0])  # unsorted repeats are fine
    t, w = gauss_legendre_nodes(bps, n, a, b)
    pieces = np.unique(np.concatenate([[a, b], bps[(bps > a) & (bps < b)]]))
    assert t.shape == w.shape == ((pieces.size - 1) * n,)
    assert abs(w.sum() - (b - a)) < 1e-13 * max(1.0, b - a)
    assert np.all(w > 0) and np.all(np.diff(t) > 0) and t.min() > a and t.max() < b
    # No node straddles a breakpoint: each piece holds exactly n nodes.
    np.testing.assert_array_equal(np.histogram(t, bins=pieces)[0], n)


def test_gauss_legendre_validation():
    with pytest.raises(ValueError):
        gauss_legendre_nodes([0.0, 1.0], 0, 0.0, 1.0)
    with pytest.raises(ValueError):
        gauss_legendre_nodes([0.0, 1.0], 2, 1.0, 0.0)


def test_refining_from_a_knot_splits_no_span_before_it():
    # 0.95 is the 19th knot of 30 spans on [0, 1.5] only up to rounding (0.9500000000000001).
    curve = DofCurve.uniform(0.0, 1.5, 30)
    knots = curve.refined(0.95, 1.0).breakpoints
    assert np.allclose(knots[(knots > 0.87) & (knots < 1.01)], [0.9, 0.95, 0.975, 1.0])   # no 0.925


@pytest.mark.parametrize("order", [0, 1, 2])
def test_evaluate_is_bsplines_value_bit_for_bit_on_any_knots(order):
    """evaluate calls scipy's spline kernel directly where it can (spline._KERNEL): the values
    must be BSpline's own, to the last bit, also on repeated knots and at the knots and ends."""
    rng = np.random.default_rng(order)
    for _ in range(5):
        interior = np.sort(rng.uniform(0.0, 2.0, 7))
        interior[3] = interior[4]                               # a double knot
        knots = np.r_[[0.0] * 4, interior, [2.0] * 4]
        curve = DofCurve(knots, rng.standard_normal(knots.size - 4))
        times = np.r_[0.0, interior, rng.uniform(0.0, 2.0, 50), 2.0]
        expected = BSpline(knots, curve.coef, 3)(times, nu=order)
        assert np.array_equal(curve.evaluate(times, order), expected)
        assert np.array_equal(curve.values_at(curve.checked_times(times), order), expected)
