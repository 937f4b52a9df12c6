"""The SQP subproblem: a convex QP with equality and inequality rows, optionally elastic.

    min ½dᵀHd + gᵀd   s.t.   A_e d + c_e = 0,   A_i d + c_i >= 0                  (hard)

    min ½dᵀHd + gᵀd + ρ·Σ(u + v) + ρ·Σt
        s.t.  A_e d + c_e + u - v = 0,  A_i d + c_i + t >= 0,  u, v, t >= 0         (elastic)

With equality rows only, the hard QP is one Lagrange–Newton (KKT) solve, the paper's step. With
inequality rows, or elastic, a primal–dual interior-point method (Mehrotra predictor–corrector)
decides which rows bind (first, from the rows that bound at the last SQP step, a few passes of
an active-set method, which settles in fewer factorizations where that guess is close); each of
its iterations solves a KKT system of the same shape,
[[H + A_iᵀ Q⁻¹ A_i, A_eᵀ], [A_e, -E]], where Q = w/z (+ t/(ρ - z)) and E = ε (+ u/(ρ + y) +
v/(ρ - y)). The elastic QP (SNOPT's elastic mode, Fletcher's Sℓ1QP) is always feasible: its
multipliers are bounded by ρ, and rows whose linearization cannot be met keep nonzero slacks.

Everything is written over :class:`~stw_tui.sos.sqp.algebra.LinearAlgebra`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stw_tui.sos.sqp.algebra import KKTSystem, LinearAlgebra, Matrix, SingularSystem, Vector
from stw_tui.sos.sqp.curvature import convex_on
from stw_tui.sos.stopping import check as check_stop

STEP_TO_BOUNDARY = 0.995   # fraction of the way to a bound an interior-point step may go
KKT_EPS = 1e-10            # small negative (2,2) block: redundant (densely sampled) constraint rows get bounded multipliers
KKT_EPS_FINE = 1e-14       # ... and the block of a KKT solve done again where KKT_EPS left its rows unmet (_finer):
FOOTPRINT = 1e-3           # by more than this share of their violation (the share the SQP accepts of a hard step),
FOOTPRINT_FLOOR = 1e-8     # and by more than this (the SQP passes its tol_violation, 1e-8 by default);
FINER_KEPT = 0.5           # kept when it leaves at most this share of the first solve's residual
IPM_TOL = 1e-11            # relative residuals and complementarity at which the interior-point method stops
IPM_MAX = 100              # interior-point iteration limit (hitting it is reported, never silent)
IPM_ACCEPTABLE = 1e-6      # when the method stalls short of IPM_TOL, its best iterate is used if it got this far
IPM_STALL = 20             # iterations without halving the best error: stalled (round-off, or an infeasible QP)
INFEASIBLE_STALL = 1       # ... of a hard QP whose equality rows are met only through huge multipliers (one: the
                           # elastic QP takes over with the same capped weight, so nothing is gained by waiting):
INFEASIBLE_MULTIPLIER = 1e6   # |y| this large, and ε|y - y0| above 1e-3 of the rows' scale
FLOOR_STALL = 5            # stalled iterations with an acceptable best iterate: the rounding floor (polish, or stop)
POLISH_TOL = 1e-9          # relative: how negative a binding row's multiplier may come out of a working-set solve ...
FEASIBLE_TOL = 1e-12       # ... and how far its step may leave another inequality row's linearization (rounding)
CROSSOVER_ERROR = 1e-4     # scaled residual below which the interior-point method tries its binding rows as the solution's
ACTIVE_SET_PASSES = 5      # factorizations the active-set method may spend before the interior-point method takes over,
ACTIVE_SET_SETTLING = 0.8  # and how much fewer rows each of its passes must change than the last


@dataclass
class QPResult:
    """A QP's step and multipliers, with what it cost and how it ended."""
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
    rows_eq: Vector | None = None     # c_e + A_e d, where the QP worked it out (its residual test)


def solve_qp(la: LinearAlgebra, H: Matrix, g: Vector, Ae: Matrix, ce: Vector, Ai: Matrix, ci: Vector,
             y0: Vector | None = None, elastic: float | None = None, tol: float = IPM_TOL,
             max_ipm: int = IPM_MAX, z0: Vector | None = None, working: Vector | None = None,
             convex: bool = False, floor: float = FOOTPRINT_FLOOR) -> QPResult:
    """Solve the QP (hard, or elastic with weight ρ = ``elastic``).

    The hard equality rows are stabilized around the previous multipliers ``y0`` (a proximal
    method of multipliers): A_e d + c_e = ε (y - y0). Redundant rows — a constraint sampled more
    densely than its spline can vary — then get bounded multipliers, and the constraints are
    still met exactly once the multipliers settle. A step that ε keeps from meeting most of its
    rows (their Schur complement smaller than ε: they would settle over dozens of steps) is
    solved again on a finer ε (:func:`_finer`).

    A hard QP with inequality rows is first tried by active-set passes from the ``working`` rows
    (a backend bool vector: those that bound at the last step), then solved by the
    interior-point method, whose solution is made exact on the rows it found binding
    (:func:`_on_working_set`): binding rows become equality rows, stabilized around ``z0`` (the
    previous inequality multipliers, >= 0) like the others. ``convex``: H is positive definite
    by construction (a Gauss-Newton model plus a positive diagonal), and the active-set method
    need not test it. ``floor``: how far a step may leave its rows unmet before :func:`_finer`
    looks at it (the SQP's: its violation tolerance).

    Raises:
        SingularSystem: a KKT matrix could not be factorized.
    """
    n, me, mi = g.shape[0], ce.shape[0], ci.shape[0]
    y0 = la.zeros(me) if y0 is None else y0
    if mi == 0 and elastic is None:
        system = la.kkt(H, Ae, KKT_EPS)
        x = system.solve(la.concat([-g, -ce - KKT_EPS * y0]))
        iterations, fallbacks = system.iterations, system.fallbacks
        rows = la.matvec(Ae, x[:n]) + ce
        residual = la.max_abs(rows)
        if _held_back(residual, la.max_abs(ce), floor):
            fine = _finer(la, lambda: la.kkt(H, Ae, KKT_EPS_FINE), la.concat([-g, -ce]), y0,
                          lambda v: la.concat([la.matvec(H, v[:n]) + la.rmatvec(Ae, v[n:]), la.matvec(Ae, v[:n])]),
                          lambda v: la.max_abs(la.matvec(Ae, v[:n]) + ce), residual)
            if fine is not None:
                system, x = fine
                iterations, fallbacks = iterations + system.iterations, fallbacks + system.fallbacks
                rows = None
        return QPResult(x[:n], x[n:], la.zeros(0), iterations, 0, fallbacks, system=system, rows_eq=rows)
    z0 = la.zeros(mi) if z0 is None else z0
    systems = la.working_set_kkt(H, Ae, Ai, KKT_EPS) if elastic is None else None
    if elastic is None and working is not None:
        guess = _active_set(la, H, g, Ae, ce, Ai, ci, y0, z0, working, convex, systems, floor)
        if guess is not None:
            return guess
    tried: dict[bytes, QPResult | None] = {}

    def polish(binding) -> QPResult | None:   # each set of rows is solved at most once
        key = la.numpy(binding).tobytes()
        if key not in tried:
            tried[key] = _on_working_set(la, H, g, Ae, ce, Ai, ci, y0, z0, binding, systems, floor)
        return tried[key]

    result, w = _interior_point(la, H, g, Ae, ce, Ai, ci, y0, elastic, tol, max_ipm,
                                None if elastic is not None else polish)
    if w is None:            # crossed over to its binding rows before converging
        return result
    if elastic is None and not result.capped:
        polished = polish(result.z > w)
        if polished is not None:
            polished.linear_iterations += result.linear_iterations
            polished.ipm_iterations, polished.fallbacks = result.ipm_iterations, result.fallbacks + polished.fallbacks
            result = polished
    return result


def _on_working_set(la, H, g, Ae, ce, Ai, ci, y0, z0, binding, systems=None,
                    floor=FOOTPRINT_FLOOR) -> QPResult | None:
    """The QP's solution if the inequality rows ``binding`` (a backend bool vector) are the ones
    that bind: one KKT factorization with them as equality rows, every row stabilized around its
    previous multiplier; None when a binding row comes out with a negative multiplier or
    another inequality row is left violated.

    Tried first with the previous step's working set: near a solution the binding rows settle,
    and the step is then exactly Newton's on them (the interior-point method, which explores
    other sets, also finds far stationary points of a QP whose model is convex only on the
    null space of its binding rows). Tried after the interior-point method on the rows it
    found binding (z > w), to make its solution exact: it stops with slacks w ≈ μ/z > 0, and
    where a binding row and equality rows are linearly dependent (a DOF held at its bound by a
    constraint: `limit ELBOW 0 2.5` with `ELBOW = 0 @ 0`), that slack is an equality residual
    that the proximal term turns into a multiplier change of w/ε, again each step: the
    dependent rows' multipliers drift apart without bound, inflate the merit weight, and make
    the steps depend on rounding.
    """
    trial = _working_set_trial(la, H, g, Ae, ce, Ai, ci, y0, z0, binding, systems, floor)
    return None if trial is None else trial.result


def _held_back(residual: float, violation: float, floor: float) -> bool:
    """Whether a KKT solve on KKT_EPS left its rows unmet (``residual``: the largest |c + A d|)
    by more than FOOTPRINT of their ``violation`` (the largest |c|) and more than ``floor``:
    then :func:`_finer` solves it again."""
    return residual > max(FOOTPRINT * violation, floor)


def _finer(la: LinearAlgebra, fine: Callable[[], KKTSystem], rhs: Vector, center: Vector,
           times: Callable[[Vector], Vector], unmet: Callable[[Vector], float],
           residual: float) -> tuple[KKTSystem, Vector] | None:
    """A KKT solve done again on the (2,2) block KKT_EPS_FINE (the system ``fine`` makes), where
    its solution on KKT_EPS was held back (:func:`_held_back`; ``residual``: how far it left
    the rows unmet, ``unmet`` measures a solution the same way). That residual is ε (y - center),
    the regularization's own: along a direction where the rows' Schur complement A H⁻¹ Aᵀ has
    an eigenvalue σ below ε, each SQP step shrinks it by only ε / (σ + ε). Rows sampled more
    densely than the spline can vary (the instances an adaptive re-solve adds) and fine knots
    have such directions: the bench's own synthetic problem crawled at ~1.2e-5 for 30 steps and
    its re-solve was undone, leaving the dense check failed (6e-3); a step left that far off its
    rows is refused by the SQP, which then pays for an elastic QP (8 to 14 interior-point
    factorizations). Returns (system, solution), or
    None: the first solution stands (the finer system is singular, or leaves more than
    FINER_KEPT of its residual — rows that cannot be met together, where a smaller ε would only
    inflate the multipliers).

    The finer system is solved with one step of iterative refinement (``times``: the product of
    [[H, Aᵀ], [A, 0]] with a solution): on a system this ill-conditioned the factorization's own
    rounding is the next floor (a 12000-row system at 2000 knots: its rows 2.3e-6 unmet either
    way, 2.8e-9 after the step)."""
    n = rhs.shape[0] - center.shape[0]
    try:
        system = fine()
        target = rhs - la.concat([la.zeros(n), KKT_EPS_FINE * center])
        finer = system.solve(target)
        finer = finer + system.solve(target - times(finer) + la.concat([la.zeros(n), KKT_EPS_FINE * finer[n:]]))
    except SingularSystem:
        return None
    if not np.all(np.isfinite(la.numpy(finer))) or unmet(finer) > FINER_KEPT * residual:
        return None
    return system, finer


def _active_set(la, H, g, Ae, ce, Ai, ci, y0, z0, binding, convex=False, systems=None,
                floor=FOOTPRINT_FLOOR) -> QPResult | None:
    """The QP's solution by a primal-dual active-set method (Hintermüller, Ito & Kunisch 2003)
    from the rows ``binding``: each pass solves with the current rows as equality rows, then
    drops those whose multiplier came out negative and adds those left violated, all at once.

    One factorization a pass: when the binding rows change little from step to step (a few
    joint limits reached or left), it finds them in two or three passes, where the
    interior-point method takes ten to forty iterations of the same cost. None (the
    interior-point method decides) when:

    * the model is not convex on the null space of the equality rows: passes then end at the
      stationary point nearest the guess, which can be a saddle or a far worse minimum than the
      interior-point method's (basketball.stw: QP objective -0.9 against -13.6). One
      factorization tests it, unless ``convex`` says H is positive definite anyway;
    * a pass changes more rows than the guess holds (far from the solution the binding rows
      change wholesale), or not ACTIVE_SET_SETTLING times fewer than the pass before;
    * a set recurs, a system is singular, or ACTIVE_SET_PASSES are spent.
    """
    seen = set()
    linear_its = fallbacks = 0
    limit = int(la.numpy(binding).sum())
    for _ in range(ACTIVE_SET_PASSES):
        check_stop()
        trial = _working_set_trial(la, H, g, Ae, ce, Ai, ci, y0, z0, binding, systems, floor)
        if trial is None:
            return None
        linear_its += trial.linear_iterations
        fallbacks += trial.fallbacks
        if trial.result is not None:
            trial.result.linear_iterations, trial.result.fallbacks = linear_its, fallbacks
            return trial.result
        change = int(la.numpy(binding != trial.next_binding).sum())
        if change > limit or (not seen and not convex and not convex_on(la, H, Ae)):   # (cheaper tests first)
            return None
        seen.add(la.numpy(binding).tobytes())
        binding, limit = trial.next_binding, ACTIVE_SET_SETTLING * change
        if la.numpy(binding).tobytes() in seen:
            return None
    return None


@dataclass
class _Trial:
    """One working-set solve: the QP's solution, or the rows to try next."""
    result: QPResult | None      # the solution, when the rows were the binding ones
    next_binding: Vector         # else: the rows kept (multiplier >= 0) and those violated
    linear_iterations: int
    fallbacks: int


def _working_set_trial(la, H, g, Ae, ce, Ai, ci, y0, z0, binding, systems=None,
                       floor=FOOTPRINT_FLOOR) -> _Trial | None:
    """The QP solved with the rows ``binding`` as equality rows (:func:`_on_working_set`), and
    whether that is its solution; None when the system is singular or the step not finite.
    ``systems``: the QP's working-set systems (LinearAlgebra.working_set_kkt), made once."""
    n, me = g.shape[0], ce.shape[0]
    c = la.concat([ce, ci[binding]])
    center = la.concat([y0, -z0[binding]])   # a binding row's equality multiplier is -z
    try:
        system = (systems or la.working_set_kkt(H, Ae, Ai, KKT_EPS))(binding)
    except SingularSystem:
        return None
    rhs = la.concat([-g, -c])
    x = system.solve(rhs - la.concat([la.zeros(n), KKT_EPS * center]))
    # Once more around the multipliers just found (the same factorization): the rows are then
    # met up to ε times rounding, not up to ε times the multipliers' change since the last step.
    x = system.solve(rhs - la.concat([la.zeros(n), KKT_EPS * x[n:]]))
    if not np.all(np.isfinite(la.numpy(x))):
        return None
    its, fallbacks = system.iterations, system.fallbacks
    slack_all = la.matvec(Ai, x[:n]) + ci

    def unmet(v, slacks):   # the largest |c + A d| over the equality and the binding rows
        return la.max_abs(la.concat([la.matvec(Ae, v[:n]) + ce, slacks[binding]]))
    residual = unmet(x, slack_all)
    if _held_back(residual, la.max_abs(c), floor):
        def times(v):   # [[H, Aᵀ], [A, 0]] v, A the equality rows and the binding ones
            bound = la.zeros(ci.shape[0])
            bound[binding] = v[n + me:]
            return la.concat([la.matvec(H, v[:n]) + la.rmatvec(Ae, v[n:n + me]) + la.rmatvec(Ai, bound),
                              la.matvec(Ae, v[:n]), la.matvec(Ai, v[:n])[binding]])
        fine = _finer(la, lambda: la.working_set_kkt(H, Ae, Ai, KKT_EPS_FINE)(binding), rhs, x[n:], times,
                      lambda v: unmet(v, la.matvec(Ai, v[:n]) + ci), residual)
        if fine is not None:
            x = fine[1]
            its, fallbacks = its + fine[0].iterations, fallbacks + fine[0].fallbacks
            slack_all = la.matvec(Ai, x[:n]) + ci
    d, y, z_bound = x[:n], x[n:n + me], -x[n + me:]
    z = la.zeros(ci.shape[0])
    z[binding] = z_bound
    slack = slack_all[~binding]
    scale_z = 1.0 + la.max_abs(z_bound)
    scale_c = 1.0 + max(la.max_abs(ce), la.max_abs(ci))
    if ((z_bound.shape[0] == 0 or float(z_bound.min()) >= -POLISH_TOL * scale_z)
            and (slack.shape[0] == 0 or float(slack.min()) >= -FEASIBLE_TOL * scale_c)):
        return _Trial(QPResult(d, y, la.maximum(z, 0.0), its, 0, fallbacks), binding, its, fallbacks)
    keep = (binding & (z >= -POLISH_TOL * scale_z)) | (~binding & (slack_all < -FEASIBLE_TOL * scale_c))
    return _Trial(None, keep, its, fallbacks)


def _unmeetable(la, y, y0, scale_c) -> bool:
    """Whether a hard QP meets its equality rows only through multipliers that run away: the
    stabilized rows A_e d + c_e = ε(y - y0) are then off by more than the SQP accepts of a step
    (an inconsistent linearization, the first steps of the arm's throw: |y| ~ 1e10). Its rounding
    floor is far above IPM_TOL, and the solver takes the elastic QP instead, with its weight capped
    at INFEASIBLE_MULTIPLIER's share: nothing is gained by stalling for IPM_STALL iterations."""
    return (la.max_abs(y) >= INFEASIBLE_MULTIPLIER
            and KKT_EPS * la.max_abs(y - y0) > 1e-3 * scale_c)


def _interior_point(la, H, g, Ae, ce, Ai, ci, y0, rho, tol, max_ipm,
                    crossover=None) -> tuple[QPResult, Vector | None]:
    """Mehrotra's predictor-corrector on the QP (elastic with weight ``rho``, else hard): its
    result and slacks w. It ends at IPM_TOL, or at its rounding floor (FLOOR_STALL iterations
    without progress once the best iterate is acceptable), or stalled (IPM_STALL; INFEASIBLE_STALL
    for a hard QP that meets its equality rows only through runaway multipliers), or at max_ipm.

    ``crossover(binding)``: the QP's exact solution on the rows ``binding`` (z > w), or None.
    Once the residuals are below CROSSOVER_ERROR it is tried on the binding rows whenever two
    iterations in a row agree on them, and the first solution ends the method, returned with
    slacks None (unless its equality rows are met only through runaway multipliers, which the
    method goes on to report). The rows settle iterations before the residuals reach IPM_TOL
    (arm_throw: from the 8th of 12), and the solution on them is what solve_qp would make of the
    converged iterate anyway: a function of the rows alone.
    """
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
    best, best_error, since_best = (d, y, z, w), np.inf, 0
    barrier_kkt = la.barrier_kkt(H, Ai, Ae)   # H, Aᵢ, Aₑ fixed: only q and e change below
    e_hard = KKT_EPS + la.zeros(me)           # a hard QP's (2,2) block: the same every iteration
    k, binding = 0, None
    for k in range(1, max_ipm + 1):
        check_stop()
        last_binding = binding
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
        binding = z > w
        if (crossover is not None and error <= CROSSOVER_ERROR and last_binding is not None
                and not la.numpy(binding != last_binding).any()):
            crossed = crossover(binding)
            if crossed is not None and not _unmeetable(la, crossed.y, y0, scale_c):
                crossed.linear_iterations += linear_its
                crossed.ipm_iterations, crossed.fallbacks = k, crossed.fallbacks + fallbacks
                return crossed, None
        if error < 0.5 * best_error:
            since_best = 0
        else:
            since_best += 1
            if since_best >= IPM_STALL or (since_best >= INFEASIBLE_STALL and not elastic
                                           and _unmeetable(la, y, y0, scale_c)):
                break
            if since_best >= FLOOR_STALL and best_error <= IPM_ACCEPTABLE:
                # Its rounding floor, short of IPM_TOL: the best iterate, as after IPM_STALL
                # stalled iterations, which come to nothing more (and a hard QP's binding rows,
                # on which solve_qp polishes it, have long settled).
                break
        if error < best_error:
            best, best_error = (d, y, z, w), error
        q_inv = z / w if not elastic else 1.0 / (w / z + t / s)
        e = KKT_EPS + (u / a + v / b) + la.zeros(me) if elastic else e_hard
        system = barrier_kkt(q_inv, e)
        minus_rd, minus_q = -r_d, -q_inv   # the same in both Newton solves below

        def newton(rc):
            """Newton direction for complementarity targets rc = (w z, t s, u a, v b) - targets."""
            ri_t = r_i + rc[0] / z
            re_t = r_e
            if elastic:
                ri_t = ri_t - rc[1] / s
                re_t = re_t - rc[2] / a + rc[3] / b
            x = system.solve(la.concat([minus_rd - la.rmatvec(Ai, q_inv * ri_t), -re_t]))
            dd, dy = x[:n], x[n:]
            dz = minus_q * (ri_t + la.matvec(Ai, dd))
            primal = [(w, (-rc[0] - w * dz) / z)]
            dual = [(z, dz)]
            if elastic:
                primal += [(t, (-rc[1] + t * dz) / s), (u, (-rc[2] - u * dy) / a), (v, (-rc[3] + v * dy) / b)]
                dual += [(s, -dz), (a, dy), (b, -dy)]
            return dd, dy, primal, dual

        products = [w * z] + ([t * s, u * a, v * b] if elastic else [])
        # Predictor (affine scaling), then Mehrotra's centring + second-order corrector.
        dd, dy, primal, dual = newton(products)
        ap = min(la.max_step(x, dx) for x, dx in primal)
        ad = min(la.max_step(x, dx) for x, dx in dual)
        gap_aff = sum(la.dot(p + ap * dp, q + ad * dq) for (p, dp), (q, dq) in zip(primal, dual))
        sigma = (gap_aff / pairs / mu) ** 3 if mu > 0 else 0.0
        dd, dy, primal, dual = newton([pq + dp * dq - sigma * mu
                                       for pq, (_, dp), (_, dq) in zip(products, primal, dual)])
        ap = min(1.0, STEP_TO_BOUNDARY * min(la.max_step(x, dx, 1e30) for x, dx in primal))
        ad = min(1.0, STEP_TO_BOUNDARY * min(la.max_step(x, dx, 1e30) for x, dx in dual))
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
        (d, y, z, w), converged = best, True
    return QPResult(d, y, z, linear_its, k, fallbacks, capped=not converged, elastic=rho), w

