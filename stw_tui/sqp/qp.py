"""The SQP subproblem: a convex QP with equality and inequality rows, optionally elastic.

    min ½dᵀHd + gᵀd   s.t.   A_e d + c_e = 0,   A_i d + c_i >= 0                  (hard)

    min ½dᵀHd + gᵀd + ρ·Σ(u + v) + ρ·Σt
        s.t.  A_e d + c_e + u - v = 0,  A_i d + c_i + t >= 0,  u, v, t >= 0         (elastic)

With equality rows only, the hard QP is one Lagrange–Newton (KKT) solve, the paper's step. With
inequality rows, or elastic, a primal–dual interior-point method (Mehrotra predictor–corrector)
decides which rows bind; each of its iterations solves a KKT system of the same shape,
[[H + A_iᵀ Q⁻¹ A_i, A_eᵀ], [A_e, -E]], where Q = w/z (+ t/(ρ - z)) and E = ε (+ u/(ρ + y) +
v/(ρ - y)). The elastic QP (SNOPT's elastic mode, Fletcher's Sℓ1QP) is always feasible: its
multipliers are bounded by ρ, and rows whose linearization cannot be met keep nonzero slacks.

Everything is written over :class:`~stw_tui.sqp.algebra.LinearAlgebra`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .algebra import KKTSystem, LinearAlgebra, Matrix, Vector

STEP_TO_BOUNDARY = 0.995   # fraction of the way to a bound an interior-point step may go
KKT_EPS = 1e-10            # small negative (2,2) block: redundant (densely sampled) constraint rows get bounded multipliers
IPM_TOL = 1e-11            # relative residuals and complementarity at which the interior-point method stops
IPM_MAX = 100              # interior-point iteration limit (hitting it is reported, never silent)
IPM_ACCEPTABLE = 1e-6      # when the method stalls short of IPM_TOL, its best iterate is used if it got this far
IPM_STALL = 20             # iterations without halving the best error: stalled (round-off, or an infeasible QP)


@dataclass
class QPResult:
    d: Vector
    y: Vector               # equality multipliers (L = R + yᵀc_e)
    z: Vector               # inequality multipliers, >= 0 (L = R - zᵀc_i)
    linear_iterations: int
    ipm_iterations: int
    fallbacks: int = 0      # iterative solves that had to be replaced by a factorization
    capped: bool = False    # the interior-point method stopped (limit or stall) short of IPM_ACCEPTABLE
    elastic: float | None = None   # ρ of an elastic QP, None for a hard one
    system: KKTSystem | None = None   # a hard equality-only QP's system [[H, A_eᵀ], [A_e, -ε]],
                                      # which the second-order correction solves again


def solve_qp(la: LinearAlgebra, H: Matrix, g: Vector, Ae: Matrix, ce: Vector, Ai: Matrix, ci: Vector,
             y0: Vector | None = None, elastic: float | None = None, tol: float = IPM_TOL,
             max_ipm: int = IPM_MAX) -> QPResult:
    """Solve the QP (hard, or elastic with weight ρ = ``elastic``).

    The hard equality rows are stabilized around the previous multipliers ``y0`` (a proximal
    method of multipliers): A_e d + c_e = ε (y - y0). Redundant rows — a constraint sampled more
    densely than its spline can vary — then get bounded multipliers, and the constraints are
    still met exactly once the multipliers settle.

    Raises:
        SingularSystem: a KKT matrix could not be factorized.
    """
    n, me, mi = g.shape[0], ce.shape[0], ci.shape[0]
    y0 = la.zeros(me) if y0 is None else y0
    if mi == 0 and elastic is None:
        system = la.kkt(H, Ae, KKT_EPS)
        x = system.solve(la.concat([-g, -ce - KKT_EPS * y0]))
        return QPResult(x[:n], x[n:], la.zeros(0), system.iterations, 0, system.fallbacks, system=system)
    return _interior_point(la, H, g, Ae, ce, Ai, ci, y0, elastic, tol, max_ipm)


def _interior_point(la, H, g, Ae, ce, Ai, ci, y0, rho, tol, max_ipm) -> QPResult:
    n, me, mi = g.shape[0], ce.shape[0], ci.shape[0]
    elastic = rho is not None
    d = la.zeros(n)
    y = la.zeros(me) if elastic else y0 * 1.0
    w = la.maximum(ci, 1.0)
    z = la.full(mi, min(1.0, rho / 2) if elastic else 1.0)
    t, u, v = (la.full(mi, 1.0), la.full(me, 1.0), la.full(me, 1.0)) if elastic else (None, None, None)
    # The duals of the slack bounds, ρ - z and ρ ± y, are variables of their own: recomputing
    # them from a large ρ would cancel to zero as the multipliers reach their bound.
    s, a, b = (rho - z, rho + y, rho - y) if elastic else (None, None, None)
    scale_d = 1.0 + la.max_abs(g)
    scale_c = 1.0 + max(la.max_abs(ce), la.max_abs(ci))
    pairs = mi + (2 * mi + 2 * me if elastic else 0)
    linear_its = fallbacks = 0
    converged = False
    # The best iterate so far, by its largest scaled residual: near the solution round-off can
    # throw the iterates off again (large elastic weights), and an infeasible hard QP never
    # converges; both stall, and the best iterate is what there is to return.
    best, best_error, since_best = (d, y, z), np.inf, 0
    k = 0
    for k in range(1, max_ipm + 1):
        r_d = la.matvec(H, d) + g + la.rmatvec(Ae, y) - la.rmatvec(Ai, z)
        r_e = la.matvec(Ae, d) + ce - KKT_EPS * (y - y0)
        r_i = la.matvec(Ai, d) + ci - w
        gap = la.dot(w, z)
        if elastic:
            r_e = r_e + u - v
            r_i = r_i + t
            gap += la.dot(t, s) + la.dot(u, a) + la.dot(v, b)
        mu = gap / pairs
        if not np.isfinite(mu):
            break
        error = max(la.max_abs(r_d) / scale_d, la.max_abs(r_i) / scale_c, la.max_abs(r_e) / scale_c,
                    mu / scale_d)
        if error <= tol:
            converged = True
            break
        if error < 0.5 * best_error:
            since_best = 0
        else:
            since_best += 1
            if since_best >= IPM_STALL:
                break
        if error < best_error:
            best, best_error = (d, y, z), error
        q_inv = z / w if not elastic else 1.0 / (w / z + t / s)
        e = KKT_EPS + (u / a + v / b if elastic else 0.0) + la.zeros(me)
        system = la.kkt(la.add(H, la.gram(Ai, q_inv)), Ae, e, exact=True)

        def newton(rc):
            """Newton direction for complementarity targets rc = (w z, t s, u a, v b) - targets."""
            ri_t = r_i + rc[0] / z
            re_t = r_e
            if elastic:
                ri_t = ri_t - rc[1] / s
                re_t = re_t - rc[2] / a + rc[3] / b
            x = system.solve(la.concat([-r_d - la.rmatvec(Ai, q_inv * ri_t), -re_t]))
            dd, dy = x[:n], x[n:]
            dz = -q_inv * (ri_t + la.matvec(Ai, dd))
            primal = [(w, (-rc[0] - w * dz) / z)]
            dual = [(z, dz)]
            if elastic:
                primal += [(t, (-rc[1] + t * dz) / s), (u, (-rc[2] - u * dy) / a), (v, (-rc[3] + v * dy) / b)]
                dual += [(s, -dz), (a, dy), (b, -dy)]
            return dd, dy, primal, dual

        products = [w * z] + ([t * s, u * a, v * b] if elastic else [])
        # Predictor (affine scaling), then Mehrotra's centring + second-order corrector.
        dd, dy, primal, dual = newton(products)
        ap = min(_max_step(x, dx) for x, dx in primal)
        ad = min(_max_step(x, dx) for x, dx in dual)
        gap_aff = sum(la.dot(p + ap * dp, q + ad * dq) for (p, dp), (q, dq) in zip(primal, dual))
        sigma = (gap_aff / pairs / mu) ** 3 if mu > 0 else 0.0
        dd, dy, primal, dual = newton([pq + dp * dq - sigma * mu
                                       for pq, (_, dp), (_, dq) in zip(products, primal, dual)])
        ap = min(1.0, STEP_TO_BOUNDARY * min(_max_step(x, dx, 1e30) for x, dx in primal))
        ad = min(1.0, STEP_TO_BOUNDARY * min(_max_step(x, dx, 1e30) for x, dx in dual))
        linear_its += system.iterations
        fallbacks += system.fallbacks
        d = d + ap * dd
        w = w + ap * primal[0][1]
        if elastic:
            t, u, v = t + ap * primal[1][1], u + ap * primal[2][1], v + ap * primal[3][1]
            s, a, b = s - ad * dual[0][1], a + ad * dy, b - ad * dy
        y = y + ad * dy
        z = z + ad * dual[0][1]
    if not converged and best_error <= IPM_ACCEPTABLE:
        (d, y, z), converged = best, True
    return QPResult(d, y, z, linear_its, k, fallbacks, capped=not converged, elastic=rho)


def _max_step(v: Vector, dv: Vector, cap: float = 1.0) -> float:
    """Largest α <= cap keeping v + α dv >= 0."""
    neg = dv < 0
    if not bool(neg.any()):
        return cap
    return float(min(cap, float((-v[neg] / dv[neg]).min())))
