""""Converged" means the same at every mesh (issue 51, part 1): the pendulum swing-up at 20 to
5120 knot spans reaches that mesh's optimum, checked against an independent solver on the same
B-spline, and the optima approach the continuous one monotonically.

The reference is written here, not through stw's compiler: the clamped cubic B-spline on uniform
knots by scipy.interpolate.BSpline, the objective ∫u² by Gauss-Legendre (4 points a span, stw's
`quadrature` default), u = th'' + g sin th, and Newton's method on the KKT system of the four
linear boundary rows (Gauss-Newton steps first, from th = pi t/2, then exact Newton steps to a
Lagrangian gradient at rounding). IPOPT reaches 68.1306 at 1280 spans on the same spline.

Tolerances: objective 1e-8 relative to the reference (the issue's accuracy); at most 30
iterations a mesh; the optima fall as the mesh refines (nested spline spaces) by gaps that
shrink, up to the rounding of the objective itself at 5120 spans (ROUNDING): u = Σ cᵢBᵢ'' + g sin th
sums terms of |Bᵢ''| ~ 6/h² = 4e7 to about 10, and the optimum there lies 5.6e-11 above the one at
1280 spans by both this reference and stw, where the spline's own gain is ~1e-12.
"""

import numpy as np
import pytest
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.interpolate import BSpline

from conftest import run_lines
from stw_tui.session.session import Session

G = 9.81
SPANS = (20, 80, 320, 1280, 5120)
CONTINUOUS = 68.1306   # IPOPT at 1280 spans, and this reference at 5120, to 6 digits
ROUNDING = 1e-10       # the objective's relative rounding at 5120 spans


def pendulum(spans: int) -> str:
    return f"""set limit knots 20000
time 0 2 knots={spans}
const g = {G}
dof th = pi*t/2
let u = th'' + g*sin(th)
constraint a: th = 0, th' = 0 @ 0
constraint b: th = pi, th' = 0 @ 2
objective effort: u
iterate 100
"""


def reference_optimum(spans: int) -> float:
    """min Σ w u(t_q)² over the control points, th(0) = th'(0) = th'(2) = 0, th(2) = pi."""
    knots = np.concatenate([[0.0] * 3, np.linspace(0.0, 2.0, spans + 1), [2.0] * 3])
    x, w = np.polynomial.legendre.leggauss(4)
    lo, hi = knots[3:-4], knots[4:-3]
    tq = ((lo + hi)[:, None] / 2 + (hi - lo)[:, None] / 2 * x).ravel()
    wq = ((hi - lo)[:, None] / 2 * w).ravel()
    n = spans + 3

    def design(t, nu):
        return _design(knots, t, nu, n)

    B0, B2 = design(tq, 0), design(tq, 2)
    ends = np.array([0.0, 2.0])
    A = sps.vstack([design(ends[:1], 0), design(ends[:1], 1), design(ends[1:], 0), design(ends[1:], 1)]).tocsr()
    b = np.array([0.0, 0.0, np.pi, 0.0])
    greville = (knots[1:-3] + knots[2:-2] + knots[3:-1]) / 3
    c = np.pi * greville / 2          # the spline of pi t/2 exactly

    def parts(c):
        th = B0 @ c
        u = B2 @ c + G * np.sin(th)
        J = (B2 + sps.diags_array(G * np.cos(th)) @ B0).tocsr()
        return th, u, J

    for k in range(60):
        th, u, J = parts(c)
        grad = 2 * J.T @ (wq * u)
        H = 2 * (J.T @ sps.diags_array(wq) @ J)
        if k >= 8:   # exact Newton once Gauss-Newton has brought it near
            H = H - 2 * (B0.T @ sps.diags_array(wq * u * G * np.sin(th)) @ B0)
        K = sps.block_array([[H, A.T], [A, None]], format="csc")
        step = spla.spsolve(K, np.concatenate([-grad, b - A @ c]))[:n]
        c = c + step
        if k >= 8 and np.abs(step).max() < 1e-13:
            break
    _, u, _ = parts(c)
    return float(wq @ u ** 2)


def _design(knots, t, nu, n):
    """BSpline.design_matrix of the nu-th derivative (scipy's design matrix holds values only)."""
    if nu == 0:
        return BSpline.design_matrix(t, knots, 3).tocsr()
    # the derivative's basis: degree 3 - nu on the inner knots, by the B-spline derivative formula
    D = sps.eye_array(n).tocsr()
    k, kn = 3, knots
    for _ in range(nu):
        m = kn.size - k - 1
        width = kn[k + 1:k + m] - kn[1:m]
        scale = np.divide(k, width, out=np.zeros_like(width), where=width > 0)
        diff = sps.diags_array([-scale, scale], offsets=[0, 1], shape=(m - 1, m)).tocsr()
        D = diff @ D
        kn, k = kn[1:-1], k - 1
    return (BSpline.design_matrix(t, kn, k) @ D).tocsr()


def solve(spans: int):
    session = run_lines(Session(), pendulum(spans))
    run = session.runs[-1]
    return run, run.reports[-1].objective


@pytest.fixture(scope="module")
def study():
    return {spans: (solve(spans), reference_optimum(spans)) for spans in SPANS}


@pytest.mark.parametrize("spans", SPANS)
def test_the_pendulum_converges_to_each_meshs_optimum(study, spans):
    (run, objective), reference = study[spans]
    assert run.converged
    assert len(run.reports) <= 30
    assert abs(objective - reference) <= 1e-8 * reference, (spans, objective, reference)


def test_the_optima_approach_the_continuous_one_monotonically(study):
    objectives = [study[spans][0][1] for spans in SPANS]
    for coarse, fine in zip(objectives, objectives[1:]):
        assert fine <= coarse * (1 + ROUNDING)
    gaps = np.abs(np.diff(objectives))
    assert all(b <= a for a, b in zip(gaps, gaps[1:]))
    assert abs(objectives[-1] - CONTINUOUS) <= 1e-6 * CONTINUOUS


def test_the_reference_is_the_spline_stw_solves():
    """The reference's design matrices against stw's own basis at 20 spans (an independent
    derivative formula must agree with scipy's BSpline derivatives)."""
    knots = np.concatenate([[0.0] * 3, np.linspace(0.0, 2.0, 21), [2.0] * 3])
    t = np.linspace(0, 2, 37)
    eye = np.eye(23)
    for nu in (0, 1, 2):
        dense = np.column_stack([BSpline(knots, eye[i], 3)(t, nu) for i in range(23)])
        np.testing.assert_allclose(_design(knots, t, nu, 23).toarray(), dense, atol=1e-9)
