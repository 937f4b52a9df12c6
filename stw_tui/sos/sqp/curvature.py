"""Curvature control of exact (Newton) models: the least shift δI that makes the QP convex where
it must be.

The QP of an SQP step with an indefinite model H steps toward any stationary point of its
model, saddles included: the SQP then crawls near saddles of the reduced Lagrangian, and whether
it leaves one, or stops there as "converged", turns on rounding (basketball.stw: scipy left a
saddle at objective 166.21 after 100 steps, torch stopped there). IPOPT corrects the inertia of
its KKT matrix; the same test without an inertia-revealing factorization: H is positive definite
on the null space of A exactly when H + ρAᵀA is for ρ large enough (Debreu's lemma), which one
Cholesky-type factorization (``LinearAlgebra.positive_definite``) answers.
"""

from __future__ import annotations

import numpy as np

from stw_tui.sos.sqp.algebra import LinearAlgebra, Matrix

# Relative to max(1, max |H_ii|), per unit row: the test is H + ρ Σᵢ aᵢaᵢᵀ/|aᵢ|². Debreu's ρ must
# outweigh H along every direction the rows constrain, also the weakly constrained ones. A ρ
# relative to the widest row (as this test once had) leaves a row in other units (a planted foot
# in metres beside flight torques in N·m, sessions/acrobat.stw) or on a finer knot span (a
# position row beside one on an acceleration, |B''| ~ 1/h²) some 1e-3 to 1e-7 of the penalty,
# and a model convex on the null space is taken for indefinite and shifted: the raw in_hand grasp
# (tests/test_refinement.py) was shifted by 40 where its reduced Hessian's least eigenvalue
# was -0.2, or positive, and crawled at the iteration limit with full steps. Scaling each row
# to unit length changes no null space. What is left is the rows' near dependence: directions
# they constrain by a singular value σ of the unit rows get ρσ² (σ ~ 5e-4 there: 0.25 of H's
# scale). Rounding sets the other side: the Cholesky test cannot see curvature below ~ε·ρ of H's
# scale, and a direction the objective leaves flat (acrobat's, curvature ~ the proximal term)
# fails it and is shifted by that much. With 1e8 that was 50 on acrobat's 2e10 (its 129
# iterations became 354); 1e6 leaves both sessions and the grasp as measured (tests/test_sqp_robust.py).
CURVATURE_PENALTY = 1e6
# The first shift tried is near the rounding floor of a Cholesky test on H's scale (a shift below
# ~n·ε_mach·max H_ii is not seen): the curvature that needs a shift can be that small. On a curve
# of span width h the smooth motions, the ones the objective's low-order terms (g·sin th, λ·∇²c)
# make indefinite, have curvature ~h of the mass matrix, against max H_ii ~ 1/h³ of an objective
# on second derivatives: 1e-11 of it at 1280 spans, 5e-14 at 5120. A first shift of 1e-10·max H_ii
# was then 10 to 2000 times the least one, and the step along those motions a crawl (the
# pendulum swing-up: 20 iterations at 1280 spans, the iteration limit at 5120; now 11 and 6).
SHIFT_FIRST, SHIFT_MAX = 1e-14, 1e-1   # first and largest shift δI tried; each try is 10x the last ...
SHIFT_BISECTIONS = 3      # ... then geometric bisections bring it within a factor 10^(1/8) of the least


def convex_on(la: LinearAlgebra, H: Matrix, A: Matrix | None) -> bool:
    """Whether H is positive definite on the null space of A (None: everywhere)."""
    return la.positive_definite(_penalized(la, H, A, max(1.0, la.max_abs_diagonal(H))))


def _penalized(la: LinearAlgebra, H: Matrix, A: Matrix | None, scale: float) -> Matrix:
    """H + ρ Σᵢ aᵢaᵢᵀ/|aᵢ|² with Debreu's ρ (CURVATURE_PENALTY, relative to H's scale), the rows
    aᵢ of A scaled to unit length (a row of zeros constrains nothing, and is left out)."""
    if A is None or not A.shape[0]:
        return H
    squares = la.row_squares(A)
    # rows below 1e-16 of the widest are zero to rounding: they would make their noise a constraint
    floor = 1e-16 * float(squares.max(initial=0.0))
    if floor <= 0:
        return H
    weights = np.where(squares > floor, CURVATURE_PENALTY * scale / np.maximum(squares, floor), 0.0)
    return la.add(H, la.gram(A, la.vector(weights)))


def convexify(la: LinearAlgebra, H: Matrix, A: Matrix | None, last: float = 0.0) -> tuple[Matrix, float]:
    """H + δI with the least δ >= 0 that makes it positive definite on the null space of A
    (None: everywhere), and δ.

    δ = 0 when H already is; else the search starts at max(SHIFT_FIRST, ``last``/3) (the shift
    the previous step needed, as IPOPT does), multiplies by 10 until the test passes and bisects
    the last decade geometrically: a shift far above the least one leaves a saddle only slowly
    (the step along a curvature -λ grows by δ/(δ-λ) per iteration). When no shift up to
    SHIFT_MAX does, H with that largest shift (a short, proximal step).
    """
    n = H.shape[0]
    scale = max(1.0, la.max_abs_diagonal(H))
    M = _penalized(la, H, A, scale)

    def convex(delta: float) -> bool:
        return la.positive_definite(la.add(M, la.diagonal_matrix(np.full(n, delta))) if delta else M)

    if convex(0.0):
        return H, 0.0
    top = SHIFT_MAX * scale
    lo, hi = 0.0, max(SHIFT_FIRST * scale, last / 3.0)
    while hi < top and not convex(hi):
        lo, hi = hi, 10.0 * hi
    hi = min(hi, top)
    for _ in range(SHIFT_BISECTIONS if lo > 0 else 0):
        mid = float(np.sqrt(lo * hi))
        lo, hi = (lo, mid) if convex(mid) else (mid, hi)
    return la.add(H, la.diagonal_matrix(np.full(n, hi))), hi


__all__ = ["convexify", "convex_on", "CURVATURE_PENALTY", "SHIFT_FIRST", "SHIFT_MAX", "SHIFT_BISECTIONS"]
