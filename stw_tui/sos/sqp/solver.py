"""SQP (Lagrange–Newton) iterations, after Cohen 1992, 3.6 — written once for every backend.

Each :meth:`SQPBackend.step` solves the QP of the Lagrangian's quadratic model over the linearized
constraints — with equality rows only, exactly the paper's system

    [[∇²L + δI + damping, Aᵀ], [A, 0]] [d; λ⁺] = [-∇R; -c]

and with inequality instances by an interior-point method whose iterations solve systems of the
same shape (qp.py). Rows whose `when` condition fails at the current iterate are left out.

Robustness, in the order a step meets it:

* **Elastic mode.** When the linearized constraints cannot be met (the hard QP's interior-point
  method reaches its iteration limit, or its KKT systems stay singular under regularization),
  the step comes from the elastic QP instead: every row relaxed by
  nonnegative slacks that cost ρ each (SNOPT's elastic mode). It is always feasible, and its
  step decreases the ℓ1 merit with weight ρ.
* **Curvature control.** An exact (Newton) model is shifted by the least δI (of a geometric
  series, refined by bisection) that makes it positive definite on the null space of the
  equality rows and the binding inequality rows (IPOPT's inertia correction, tested through a
  Cholesky factorization of H + ρAᵀA): the QP then steps away from saddles of the reduced
  Lagrangian instead of toward them. Where the model is convex only there, a step that restores
  feasibility may climb the objective; the merit weight is raised to what such a step needs.
* **Model choice** (option `hessian`). `auto` takes Gauss-Newton steps while far from feasible and
  tries the exact Hessian first near it; after two or more exact steps refused in a row it takes
  1, 2, 4 Gauss-Newton steps before trying the exact one again (:func:`_newton_backoff`).
* **Working set.** The QP is first solved with the rows that bound at the last step as equality
  rows (one KKT solve: Newton's step once they settle), and by the interior-point method only
  when that guess fails; its solution is then made exact on the rows it found binding.
* **Step limit** (option `trust`). A trust radius bounds the largest change of any control point; it adapts by
  the ratio of the merit's actual to predicted decrease, so near the optimum full (Newton) steps
  are taken and fast local convergence is kept. A refused step is retried with a heavier proximal
  (Levenberg–Marquardt) term and a smaller radius; backtracking comes last.
* **Acceptance.** A step must decrease the ℓ1 merit R + Σ ρᵢ·violationᵢ by a fraction of what the
  model predicts, with one second-order correction against the Maratos effect. Once nearly
  feasible, each row is weighed by its own multiplier (SQPBackend._merit_weights). With the option
  `growth`, it may not multiply the objective by more than that factor (once the objective is
  above max(1, ℓ1 violation)): a large merit weight must not let one step blow the motion up.
* **Infeasibility.** When elastic steps make no more progress while rows stay violated (no step,
  or one that lowers their ℓ1 violation neither to first order nor in fact; after the elastic
  weight has been raised), the problem is declared infeasible, and the constraints in conflict
  are named: those whose rows carry the multipliers of the least-violation QP.

Backends supply a :class:`~stw_tui.sos.sqp.algebra.LinearAlgebra` (where vectors live, how the KKT
system is solved) and optionally their own evaluator of the window problem (torch's programs).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from stw_tui.sos.backend import Backend, BackendOption, Capability, SolverState, StepReport
from stw_tui.sos.sqp.algebra import LinearAlgebra, SingularSystem
from stw_tui.sos.sqp.curvature import convexify
from stw_tui.sos.sqp.qp import FOOTPRINT_FLOOR, INFEASIBLE_MULTIPLIER, KKT_EPS, QPResult, solve_qp
from stw_tui.sos.stopping import check as check_stop
from stw_tui.sos.stopping import stoppable
from stw_tui.sos.sqp.termination import is_converged, kkt_residual
from stw_tui.sym.errors import StwError

PROX_MIN, PROX_MAX = 1e-10, 1e8   # range of the adaptive proximal (Levenberg-Marquardt) term
RETRIES = 5              # a refused full step is retried with 10x, 100x, ... heavier proximal terms
ETA = 1e-4               # Armijo: accept a step whose merit decrease is this share of the slope's
RATIO_POOR, RATIO_GOOD = 0.25, 0.75   # trust-radius update: shrink below, grow above (when it bound)
RATIO_EXACT = 1e-9      # |ratio - 1| up to which the model predicted a step exactly (rounding)
RADIUS_FLOOR, RADIUS_CEILING = 1e-6, 1e2   # the step limit stays within these multiples of its start
MIN_STEP = 1e-8          # smallest backtracking step before declaring a stall
ACTIVE_FRACTION = 1e-6   # an inequality whose multiplier exceeds this share of the largest binds
OBJECTIVE_FLOOR = 1.0    # option `growth` bounds the objective's growth once it is above this
ELASTIC_WEIGHT = 1e2     # elastic slack cost: this x max(1, |∇R|, |λ|) ...
ELASTIC_RAISE, ELASTIC_MAX = 1e2, 1e6   # ... raised by this factor, up to this x max(1, |∇R|)
NEWTON_WAIT_MAX = 4      # most Gauss-Newton steps taken before an exact one is tried again
CONFLICT_FRACTION = 0.1  # a group with this share of the least-violation multipliers is in conflict
MULTIPLIER_MARGIN = 1.5  # a row's merit weight: this x its multiplier (at least)
STATIONARY_VIOLATION = 1e-6   # an elastic step that lowers the linearized violation by less: stationary

SQP_OPTIONS = (
    BackendOption("trust", float, 0.5, "initial step limit: largest change of any control point "
                  "in one iteration, times max(1, largest control point); it adapts by the merit's "
                  "ratio test (0: no limit)", minimum=0.0),
    BackendOption("growth", float, 0.0, "largest factor by which one step may multiply the "
                  "objective (above max(1, violation)); 0: no bound", minimum=0.0),
    BackendOption("max_step", float, 0.0, "a fixed cap on the change of any control point in one "
                  "iteration (0: no cap)", minimum=0.0),
    BackendOption("hessian", str, "auto", "Hessian of the Lagrangian: exact (Newton), "
                  "gauss_newton (objective residuals only: positive semidefinite), or auto "
                  "(Gauss-Newton until nearly feasible, then exact, backing off to Gauss-Newton for a few "
                  "steps while exact steps are refused)", ("auto", "exact", "gauss_newton")),
    BackendOption("prox", float, 1e-6, "initial proximal (Levenberg-Marquardt) weight; it adapts",
                  minimum=0.0),
    BackendOption("newton_switch", float, 1e-2, "max violation below which `auto` uses the "
                  "exact Hessian", minimum=0.0),
)


@dataclass
class SQPInner:
    """The SQP's own state between steps."""

    state: SolverState
    ev: Any                   # the evaluation at state.s
    settings: dict
    evaluator: Any            # evaluates the window problem (the problem itself, or a lowering)
    algebra: LinearAlgebra
    shift: float = 0.0        # the last curvature shift δ an exact model needed (see _convexify)
    damping: Any = None       # 2 x the evaluator's damping per variable, read once per solve
    speculate: bool = False   # the next step's first trial is evaluated whole (see SQPBackend._accept)
    violation: float | None = None   # ev's max violation, where the last step worked it out


@dataclass
class _Linearization:
    """The constraint rows of one iterate, as backend vectors and matrices."""

    eq_rows: np.ndarray
    ge_rows: np.ndarray
    g: Any
    Ae: Any
    ce: Any
    Ai: Any
    ci: Any
    y0: Any
    z0: Any                   # the previous inequality multipliers (>= 0) of the live rows
    working: Any              # the live rows that bound at the last step (backend bool vector)


@dataclass
class _Subproblem:
    """A solved QP, in numpy, with what the acceptance test and the report need."""

    qp: QPResult
    d: np.ndarray
    lam_eq: np.ndarray
    lam_ge: np.ndarray
    working: np.ndarray
    lin_eq: np.ndarray        # c_e + A_e d over the live equality rows
    lin_ge: np.ndarray        # c_i + A_i d over the live inequality rows
    H: Any                    # the regularized Hessian it was solved with


@dataclass
class _Counts:
    linear_iterations: int = 0
    fallbacks: int = 0
    capped: int = 0
    elastic: bool = False


@dataclass
class _Trial:
    alpha: float
    d: np.ndarray
    ratio: float = 0.0
    values: Any = None   # the merit values at the accepted point (MeritValues), when tested,
    whole: bool = False  # ... or its whole Evaluation (speculative, see _accept)
    first: bool = False  # the step passed its first test (no correction, no backtracking)


def _live(la: LinearAlgebra, mask: np.ndarray, rows: np.ndarray):
    """A bool ``mask`` over every inequality row, on the live ``rows`` only, as a backend vector."""
    return la.vector(mask[rows].astype(float)) > 0.5


class SQPBackend(Backend):
    """The shared SQP. Subclasses implement :meth:`algebra` (and may override :meth:`evaluator`)."""

    options = SQP_OPTIONS
    capabilities = frozenset({Capability.INEQUALITIES, Capability.CONDITIONAL, Capability.DAMPING,
                              Capability.WEIGHTS, Capability.ELASTIC})
    bounded_calls = True   # a step's loops (retries, QP iterations) all have limits

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        # A subclass with its own init or step makes no such promise unless it says so itself.
        if "bounded_calls" not in cls.__dict__ and {"init", "step"} & cls.__dict__.keys():
            cls.bounded_calls = False

    # --- what a backend supplies ------------------------------------------------------------
    def algebra(self, problem) -> LinearAlgebra:
        """The linear algebra the SQP runs on."""
        raise NotImplementedError

    def evaluator(self, problem, algebra: LinearAlgebra):
        """What evaluates the problem: ``evaluate(s)``, ``merit_values(s)`` and ``damping`` as
        :class:`~stw_tui.sos.window.WindowProblem` has them (the default: the problem itself).
        One that computes second derivatives only on demand may also have
        ``expect_hessian(used)``: before evaluating a new point, the SQP says there whether the
        next step will ask for that evaluation's Lagrangian Hessian (stw_torch's TorchProblem);
        before a trial point evaluated ahead of its merit test (:meth:`_accept`'s
        ``speculate``), whether the SQP may use an exact Hessian at all. The Hessian must still
        come when asked for after a wrong guess."""
        return problem

    # --- init / state -----------------------------------------------------------------------
    def init(self, problem, state: SolverState, settings) -> SQPInner:
        la = self.algebra(problem)
        evaluator = self.evaluator(problem, la)
        return SQPInner(state=state, ev=evaluator.evaluate(state.s), settings=dict(settings),
                        evaluator=evaluator, algebra=la, damping=2.0 * evaluator.damping)

    def state(self, inner: SQPInner) -> SolverState:
        return inner.state

    # --- one iteration -----------------------------------------------------------------------
    def step(self, problem, inner: SQPInner, iteration: int) -> tuple[SQPInner, StepReport]:
        """One SQP iteration. After the first, a stop asked for meanwhile (the driver's
        ``settings[CANCELLED]``) ends it early with StepStopped (stopping.py); the first always
        completes, so a stopped solve has at least one iteration to keep (`iterate K`, K >= 1)."""
        from stw_tui.sos.backend import CANCELLED

        with stoppable(inner.settings.get(CANCELLED) if iteration > 1 else None):
            return self._step(problem, inner, iteration)

    def _step(self, problem, inner: SQPInner, iteration: int) -> tuple[SQPInner, StepReport]:
        ms: dict[str, float] = {"assemble": 0.0, "solve": 0.0, "line_search": 0.0}
        la, st, ev, settings = inner.algebra, inner.state, inner.ev, inner.settings
        counts = _Counts()
        clock = time.perf_counter()
        lin = self._linearize(la, ev, st)
        start_violation = ev.max_violation() if inner.violation is None else inner.violation
        far = start_violation > self.config["newton_switch"]   # for the merit weights, as for the modes
        modes = self._modes(start_violation, st.newton_wait)
        prox = st.regularization if st.regularization > 0 else self.config["prox"]
        ceiling = self._initial_radius(ev.s)
        floor = RADIUS_FLOOR * ceiling
        radius = st.trust_radius if st.trust_radius > 0 else ceiling
        ceiling *= RADIUS_CEILING
        rho_elastic = st.elastic_weight
        ms["assemble"] += _lap(clock)
        # A refused full step is retried with a heavier proximal term (shorter, better-modelled
        # steps) before any backtracking; an exact step also as Gauss-Newton. Last: backtracking.
        attempts = [(mode, prox, False) for mode in modes] + \
            [(modes[-1], min(PROX_MAX, prox * 10.0 ** k), False) for k in range(1, RETRIES)] + \
            [(modes[-1], prox, True)]
        trial, sub, rho, capped = _Trial(0.0, np.zeros(ev.s.size)), None, st.merit_weight, False
        models: dict[str, Any] = {}   # the model Hessian of each mode: only the proximal term changes
        damping = inner.damping
        shift = inner.shift
        refused = None   # (mode, the rows that bound) of a refused hard QP with inequality rows
        exact_refused = None   # whether the exact Hessian's step was refused (None: not tried)
        speculate = inner.speculate   # for the first trial only
        for attempt, (mode, prox, backtrack) in enumerate(attempts):
            check_stop()
            clock = time.perf_counter()
            if mode not in models:
                models[mode] = la.matrix(
                    ev.gauss_newton() if mode == "gauss_newton" else
                    ev.lagrangian_hessian(st.lam_eq * ev.active_eq, st.lam_ge * ev.active_ge))
            H_model = models[mode]
            H = la.add(H_model, la.diagonal_matrix(damping + prox))
            if mode == "exact":
                H, shift = self._convexify(la, H, ev, lin, st, inner.shift)
            ms["assemble"] += _lap(clock)

            clock = time.perf_counter()
            # Gauss-Newton (2JᵀWJ, weights >= 0) plus a positive diagonal is positive definite
            convex = mode == "gauss_newton" and float(np.min(damping + prox, initial=1.0)) > 0
            # A retry of the same mode differs in its proximal term only: the rows that bound in
            # the refused attempt are a closer guess than the last step's (luxo's and acrobat's
            # retries settle by active-set passes instead of 9-17 interior-point iterations).
            guess = lin if refused is None or refused[0] != mode else replace(lin, working=refused[1])
            sub, rho_elastic = self._subproblem(la, H, ev, guess, rho_elastic, settings, counts, convex)
            ms["solve"] += _lap(clock)
            if sub is None:
                continue
            clock = time.perf_counter()
            weights = self._merit_weights(la, ev, lin, sub, settings, far)
            rho = max(float(weights[0].max(initial=0.0)), float(weights[1].max(initial=0.0)))
            d = sub.d
            biggest = float(np.abs(d).max(initial=0.0))
            limit = min(radius, self.config["max_step"] or np.inf)
            capped = biggest > limit
            if capped:
                d = d * (limit / biggest)
            trial = self._accept(la, inner.evaluator, ev, lin, sub, H_model, d, weights,
                                 backtrack=backtrack, speculate=speculate)
            speculate = False
            ms["line_search"] += _lap(clock)
            if mode == "exact" and exact_refused is None:
                exact_refused = trial.alpha == 0
            if trial.alpha > 0:
                break
            radius = max(floor, 0.5 * min(radius, float(np.abs(d).max(initial=0.0))))
            if sub.qp.elastic is None and lin.ci.shape[0]:
                refused = mode, _live(la, sub.working, lin.ge_rows)
        if sub is None:
            raise StwError("the KKT system stayed singular under regularization: are two "
                           "constraints contradicting each other?")

        clock = time.perf_counter()
        alpha, d = trial.alpha, trial.d
        stalled = alpha == 0.0
        s_new = ev.s + alpha * d
        # The QP's multipliers are the estimate at this point whatever the step length (a damped
        # update would freeze them, and the Hessian with them, while steps are short).
        lam_eq, lam_ge = sub.lam_eq, sub.lam_ge
        refusals, wait = _newton_backoff(st, exact_refused)
        if (not stalled and not trial.whole and trial.values is not None
                and hasattr(inner.evaluator, "expect_hessian")):
            # an evaluator that computes second derivatives only on demand (torch) is told
            # whether the next step will try the exact Hessian: the violation at the new point
            # is known from its merit test (a whole trial evaluation was told before, in _accept)
            inner.evaluator.expect_hessian("exact" in self._modes(problem.max_violation(trial.values), wait))
        new_ev = ev if stalled else trial.values if trial.whole else inner.evaluator.evaluate(s_new)
        ms["evaluate"] = _lap(clock)

        kkt = kkt_residual(new_ev, lam_eq, lam_ge, self._newton(la, ev, lin, sub))
        violation = new_ev.max_violation()
        step_norm = alpha * float(np.abs(d).max(initial=0.0))
        tiny_step = step_norm <= settings["tol_step"] * (1.0 + float(np.abs(s_new).max(initial=0.0)))
        converged = is_converged(violation, kkt, settings, tiny_step, stalled)
        stalled = stalled and not converged
        infeasible, message = False, ""
        no_direction = float(np.abs(sub.d).max(initial=0.0)) <= 1e-8 * (1.0 + float(np.abs(ev.s).max(initial=0.0)))
        if counts.elastic and violation > settings["tol_violation"] and (
                no_direction or _no_progress(ev, new_ev, lin, sub)):
            if rho_elastic < ELASTIC_MAX * self._elastic_base(ev):
                rho_elastic *= ELASTIC_RAISE      # weigh the violation more, and try again
                stalled = False
            else:
                infeasible = True
                conflicts = self._conflicts(problem, la, ev, lin)
                message = _conflict_message(conflicts, violation, problem)
        radius = self._update_radius(radius, trial, d, floor, ceiling)
        # Full steps: trust the model more; cut or capped steps: less — a heavier proximal term
        # shortens the next QP step itself (Levenberg-Marquardt), which scaling a step does not.
        # A capped step whose model predicted the merit well was cut by the limit, not by a bad
        # model: the growing radius lengthens the next one, and the proximal term stays light.
        well_modelled = alpha == 1.0 and (not capped or trial.ratio > RATIO_GOOD)
        prox = max(PROX_MIN, prox / 3) if well_modelled else min(PROX_MAX, prox * 10)
        # Every field named, not dataclasses.replace (which costs twice as much; 3% of a small solve)
        new_state = SolverState(s=s_new, lam_eq=lam_eq, lam_ge=lam_ge, working_set=sub.working,
                                merit_weight=rho, regularization=prox, trust_radius=radius,
                                elastic_weight=rho_elastic, newton_refusals=refusals, newton_wait=wait)
        report = StepReport(iteration=iteration, objective=new_ev.objective, max_violation=violation,
                            kkt_residual=kkt, step_length=alpha, linear_iterations=counts.linear_iterations,
                            active=int(sub.working.sum()), ms=ms, converged=converged, stalled=stalled,
                            message=message, fallbacks=counts.fallbacks, qp_capped=counts.capped,
                            elastic=counts.elastic, infeasible=infeasible,
                            conflicts=conflicts if infeasible else (), coefficients=problem.scatter(s_new))
        # A step whose first attempt passed its first test (no retry, correction or backtracking):
        # the next one likely will too (acrobat 20 of 26 such, basketball 35 of 48).
        speculate = trial.first and attempt == 0
        return SQPInner(state=new_state, ev=new_ev, settings=settings, evaluator=inner.evaluator, algebra=la,
                        shift=shift, damping=inner.damping, speculate=speculate, violation=violation), report

    # --- pieces of a step ---------------------------------------------------------------------
    def _modes(self, violation: float, newton_wait: int) -> tuple[str, ...]:
        """Which Hessians to try at a point of this ``violation``. "auto": Gauss-Newton while far
        from feasible (the multipliers, and so the constraint curvature, mean little there),
        exact Newton near it, unless exact steps were refused lately (:func:`_newton_backoff`)."""
        choice = self.config["hessian"]
        if choice != "auto":
            return (choice,)
        if violation > self.config["newton_switch"] or newton_wait > 0:
            return ("gauss_newton",)
        return ("exact", "gauss_newton")

    @staticmethod
    def _convexify(la: LinearAlgebra, H, ev, lin: _Linearization, st: SolverState, last: float):
        """:func:`~.curvature.convexify` on the null space of the equality rows and of the
        binding inequality rows: those of the last working set, and those violated now."""
        rows = [lin.Ae] if lin.eq_rows.size else []
        if lin.ge_rows.size:
            binding = st.working_set[lin.ge_rows] | (ev.c_ge[lin.ge_rows] <= 0.0)
            if binding.any():
                rows.append(la.rows(lin.Ai, np.flatnonzero(binding)))
        A = None if not rows else la.stack_rows(rows) if len(rows) > 1 else rows[0]
        return convexify(la, H, A, last)

    def _initial_radius(self, s: np.ndarray) -> float:
        trust = self.config["trust"]
        return trust * max(1.0, float(np.abs(s).max(initial=0.0))) if trust > 0 else np.inf

    @staticmethod
    def _update_radius(radius: float, trial: _Trial, d: np.ndarray, floor: float, ceiling: float) -> float:
        """Shrink the step limit after a poorly predicted step, grow it after a well predicted one."""
        taken = trial.alpha * float(np.abs(d).max(initial=0.0))
        if trial.alpha == 0.0 or trial.ratio < RATIO_POOR:
            return max(floor, 0.5 * min(radius, taken)) if taken > 0 else radius
        if trial.alpha == 1.0 and taken >= 0.99 * radius and abs(trial.ratio - 1.0) <= RATIO_EXACT:
            # A step stopped by the limit along which the model predicted the merit exactly: the
            # problem is a QP there (linear constraints, quadratic objective), and doubling the
            # limit step by step only delays the step the model already has (cat_mouse's full
            # solve: 3 iterations to 2). Nonlinear sessions' limited steps miss 1 by 1.7e-4 or more.
            return ceiling
        if trial.ratio > RATIO_GOOD:
            return min(ceiling, 2.0 * radius)
        if trial.alpha == 1.0 and taken >= 0.99 * radius:
            # A full step stopped by the limit, with a fair ratio: the ℓ1 merit's kink (Maratos)
            # keeps the ratio below RATIO_GOOD near a solution, and a radius that never grows
            # there turns Newton's convergence into a crawl at the limit.
            return min(ceiling, 2.0 * radius)
        return radius

    @staticmethod
    def _elastic_base(ev) -> float:
        return max(1.0, float(np.abs(ev.gradient).max(initial=0.0)))

    def _linearize(self, la: LinearAlgebra, ev, st: SolverState) -> _Linearization:
        eq_rows, ge_rows = np.flatnonzero(ev.active_eq), np.flatnonzero(ev.active_ge)
        # every row of a kind live (no `when`, or all hold): its arrays as they are, not picked
        every_eq, every_ge = eq_rows.size == ev.c_eq.size, ge_rows.size == ev.c_ge.size
        J_eq, J_ge = la.jacobian(ev, "eq"), la.jacobian(ev, "ge")
        return _Linearization(eq_rows, ge_rows, la.vector(ev.gradient),
                              J_eq if every_eq else la.rows(J_eq, eq_rows),
                              la.vector(ev.c_eq if every_eq else ev.c_eq[eq_rows]),
                              J_ge if every_ge else la.rows(J_ge, ge_rows),
                              la.vector(ev.c_ge if every_ge else ev.c_ge[ge_rows]),
                              la.vector(st.lam_eq if every_eq else st.lam_eq[eq_rows]),
                              la.vector(-(st.lam_ge if every_ge else st.lam_ge[ge_rows])),
                              _live(la, st.working_set, ge_rows))

    def _subproblem(self, la, H, ev, lin: _Linearization, rho_elastic: float, settings,
                    counts: _Counts, convex: bool = False) -> tuple[_Subproblem | None, float]:
        """The hard QP's step when its linearization can be met; the elastic QP's otherwise
        (``convex``: H is positive definite by construction)."""
        # a step may leave its rows unmet by up to tol_violation before qp._finer solves it again
        floor = float(settings["tol_violation"])
        if not lin.ge_rows.size:   # equality rows only: the paper's step, one KKT solve
            newton = self._equality_qp(la, H, ev, lin, counts, floor)
            if newton is not None:
                return newton, rho_elastic
        hard = self._qp(la, H, ev, lin, None, counts, convex, floor)
        if (hard is None or hard.qp.capped) and (la.max_abs(lin.y0) > 0 or la.max_abs(lin.z0) > 0):
            # Once more from cold multipliers, before the elastic QP: the stabilization centres
            # the QP's multipliers on the last step's, and an elastic step's can be far off
            # (its slack prices, up to ρ, and a free choice along nearly dependent rows). On the
            # acrobat's ballistic phase with a 30 cm sole they were 1.3e8 against IPOPT's 6.3e3
            # on the same QP; every warm interior-point solve stalled, and the SQP declared the
            # constraints infeasible at violation 8.9e-5. From zero the same QP solves.
            cold = self._qp(la, H, ev, replace(lin, y0=la.zeros(lin.eq_rows.size),
                                               z0=la.zeros(lin.ge_rows.size)), None, counts, convex, floor)
            if cold is not None and not cold.qp.capped:
                hard = cold
        if hard is not None and not hard.qp.capped and self._meets(la, lin, hard):
            return hard, rho_elastic
        multipliers = float(np.abs(hard.lam_eq).max(initial=0.0)) if hard is not None else 0.0
        rho_elastic = max(rho_elastic, ELASTIC_WEIGHT * max(self._elastic_base(ev),
                                                            min(multipliers, INFEASIBLE_MULTIPLIER)))
        counts.elastic = True
        return self._qp(la, H, ev, lin, rho_elastic, counts), rho_elastic

    def _equality_qp(self, la, H, ev, lin: _Linearization, counts: _Counts, floor: float) -> _Subproblem | None:
        """The hard QP without live inequality rows, as :meth:`_qp` and :meth:`_meets` would
        have it when its first KKT solve succeeds and meets the rows; None otherwise (singular,
        not finite, or unmet: the general path then tries again). Without their regularization
        loop, which cost 2% of the pendulum's `iterate`."""
        try:
            qp = solve_qp(la, H, lin.g, lin.Ae, lin.ce, lin.Ai, lin.ci, y0=lin.y0, floor=floor)
        except SingularSystem:
            return None
        if not np.isfinite(la.numpy(qp.d)).all():
            return None
        sub = self._solved(la, ev, lin, qp, H)
        if not self._meets(la, lin, sub):
            return None
        counts.linear_iterations += qp.linear_iterations
        counts.fallbacks += qp.fallbacks
        return sub

    @staticmethod
    def _meets(la, lin: _Linearization, sub: _Subproblem) -> bool:
        """Whether a hard QP's step meets the linearized constraints. The QP's equality rows are
        regularized (KKT_EPS): on an inconsistent linearization (a bound against a constraint) it
        can "converge" with huge multipliers instead of failing, and that step must not pass.
        The residual is the QP's own ``lin_eq``/``lin_ge`` (c + A d, as _qp computed them)."""
        residual = max(float(np.abs(sub.lin_eq).max(initial=0.0)), float(-sub.lin_ge.min(initial=0.0)))
        before = max(float(np.abs(la.numpy(lin.ce)).max(initial=0.0)), float(-la.numpy(lin.ci).min(initial=0.0)))
        return residual <= max(1e-6, 1e-3 * before)

    def _qp(self, la: LinearAlgebra, H, ev, lin: _Linearization, elastic: float | None,
            counts: _Counts, convex: bool = False, floor: float = FOOTPRINT_FLOOR) -> _Subproblem | None:
        """Solve the QP, raising a diagonal shift while its KKT systems are singular or (elastic QP:
        no equality rows to restrict the model to) its step meets negative curvature."""
        n = ev.s.size
        reg, qp, Hr = 0.0, None, H
        for _attempt in range(8):
            check_stop()
            Hr = la.add(H, la.diagonal_matrix(np.full(n, reg))) if reg else H
            try:
                qp = solve_qp(la, Hr, lin.g, lin.Ae, lin.ce, lin.Ai, lin.ci, y0=lin.y0, elastic=elastic,
                              z0=lin.z0, working=lin.working, convex=convex, floor=floor)
            except SingularSystem:
                qp = None
                reg = max(10 * reg, 1e-8)
                continue
            counts.linear_iterations += qp.linear_iterations
            counts.fallbacks += qp.fallbacks
            counts.capped += int(qp.capped)
            if not np.isfinite(la.numpy(qp.d)).all():
                qp = None
                reg = max(10 * reg, 1e-8)
                continue
            if elastic is None:
                # A hard QP's model is convex where it counts, on the null space of its binding
                # rows (_convexify); along a step that also restores feasibility, dᵀHd < 0 is
                # no sign of trouble, and a shift there would cost Newton's local convergence.
                break
            curvature = la.dot(qp.d, la.matvec(Hr, qp.d))
            if curvature >= -1e-12 * la.dot(qp.d, qp.d) or la.max_abs(qp.d) == 0.0:
                break
            reg = max(10 * reg, 1e-6 * max(1.0, la.max_abs_diagonal(H)))
        return None if qp is None else self._solved(la, ev, lin, qp, Hr)

    @staticmethod
    def _solved(la, ev, lin: _Linearization, qp: QPResult, H) -> _Subproblem:
        """A solved QP (with model ``H``) as the SQP reads it: multipliers and working set over
        every row, and the linearized rows after the step (the QP's own c + A d where it made it)."""
        lam_eq = np.zeros(ev.c_eq.size)
        lam_eq[lin.eq_rows] = la.numpy(qp.y)
        lam_ge = np.zeros(ev.c_ge.size)
        working = np.zeros(ev.c_ge.size, bool)
        lin_ge = np.zeros(0)
        if lin.ge_rows.size:
            z = la.numpy(qp.z)
            lam_ge[lin.ge_rows] = -z          # L = R + Σλc: a binding h >= 0 has λ <= 0
            working[lin.ge_rows[z > ACTIVE_FRACTION * max(1.0, float(z.max()))]] = True
            lin_ge = la.numpy(la.matvec(lin.Ai, qp.d) + lin.ci)
        lin_eq = la.numpy(la.matvec(lin.Ae, qp.d) + lin.ce if qp.rows_eq is None else qp.rows_eq)
        return _Subproblem(qp, la.numpy(qp.d), lam_eq, lam_ge, working, lin_eq, lin_ge, H)

    def _merit_weights(self, la, ev, lin: _Linearization, sub: _Subproblem, settings, far: bool):
        """The ℓ1 merit's weight of each row, (equality rows, inequality rows).

        Each row weighs MULTIPLIER_MARGIN x its own multiplier (Powell's weighted ℓ1 merit, exact
        as any weight above |λᵢ| is), and at least the option `merit` (and, for a hard step,
        :meth:`_descent_weight`). With one weight for all, the largest multiplier priced every
        row: near a solution, where a step along the curved constraints raises their violation
        by O(|d|²) (the Maratos effect), rows whose multipliers were 1e-3 to 6e-2 cost 1.7e3 a
        unit, and steps that lowered the objective as modelled were refused over and over
        (acrobat's second solve refused 19 in its 34 iterations; with twice the knots, 47 in 60,
        at its iteration limit).

        An elastic step's rows weigh at most its slack cost ρ: the rows it leaves unmet carry
        multipliers of ρ and so weigh ρ, and the step descends that merit as it does ρ·Σ viol
        (its directional derivative is at most -dᵀHd). With ρ on every row, 1e8 where the
        multipliers are large, a 3.7e-3 step near feasibility that raised the violation by
        1.4e-6 cost 136 and was refused: basketball with twice the knots refused 14 such
        elastic steps (226 iterations, 15.7 s; now none, 217 iterations, 11.7 s).

        ``far`` from feasible (the step's start violates a row by more than `newton_switch`),
        every row weighs at least the largest multiplier (ρ on an elastic step): weighted rows
        there led luxo and basketball to other optima, 12% and 4% worse."""
        elastic = sub.qp.elastic
        if elastic is not None and far:
            return np.full(ev.c_eq.size, elastic), np.full(ev.c_ge.size, elastic)
        least = float(settings.get("merit", 1.0))
        if elastic is None:
            least = max(least, self._descent_weight(la, ev, lin, sub))
        w_eq, w_ge = MULTIPLIER_MARGIN * np.abs(sub.lam_eq), MULTIPLIER_MARGIN * np.abs(sub.lam_ge)
        if far:
            least = max(least, float(w_eq.max(initial=0.0)), float(w_ge.max(initial=0.0)))
        w_eq, w_ge = np.maximum(w_eq, least), np.maximum(w_ge, least)
        if elastic is not None:
            w_eq, w_ge = np.minimum(w_eq, elastic), np.minimum(w_ge, elastic)
        return w_eq, w_ge

    def _accept(self, la, evaluator, ev, lin: _Linearization, sub: _Subproblem, H_model, d, weights,
                backtrack: bool, speculate: bool = False) -> _Trial:
        """Test the step ``d`` (a multiple τ of the QP's step) against the ℓ1 merit
        φ = R + Σ ρᵢ·violᵢ (``weights``: ρ of the equality rows, of the inequality rows):
        accept when φ decreases by ETA x the model's prediction and the objective does not grow
        by more than the option `growth` allows; else try one second-order correction, and (``backtrack``)
        halve the step."""
        w_eq, w_ge = weights

        def merit(mv) -> float:
            eq = w_eq[mv.active_eq] @ np.abs(mv.c_eq[mv.active_eq])
            ge = w_ge[mv.active_ge] @ np.maximum(0.0, -mv.c_ge[mv.active_ge])
            return mv.objective + eq + ge

        phi0 = merit(ev)
        c_eq, c_ge = ev.c_eq[lin.eq_rows], ev.c_ge[lin.ge_rows]
        we, wg = w_eq[lin.eq_rows], w_ge[lin.ge_rows]
        full = float(np.abs(sub.d).max(initial=0.0))
        tau = float(np.abs(d).max(initial=0.0)) / full if full > 0 else 0.0
        g_d = float(ev.gradient @ d)
        d_alg = la.vector(d)
        dHd = la.dot(d_alg, la.matvec(H_model, d_alg))
        viol0 = we @ np.abs(c_eq) + wg @ np.maximum(0.0, -c_ge)

        def linearized(a: float) -> float:
            """The weighted violation of the linearization a share ``a`` of the QP's step away."""
            lin_eq = c_eq + a * (sub.lin_eq - c_eq)
            lin_ge = c_ge + a * (sub.lin_ge - c_ge)
            return we @ np.abs(lin_eq) + wg @ np.maximum(0.0, -lin_ge)

        def predicted(alpha: float) -> float:
            return -(alpha * g_d + 0.5 * alpha * alpha * dHd) + (viol0 - linearized(alpha * tau))

        # Armijo on the merit's directional derivative along d (the linearization's violation
        # after the full step is what the merit expects to lose).
        # A hard QP step meets the linearization (up to the linear solver's accuracy, which must
        # not count as progress); an elastic one leaves its slacks.
        viol_after = 0.0 if sub.qp.elastic is None else linearized(tau)
        slope = g_d - (tau * viol0 if sub.qp.elastic is None else viol0 - viol_after)
        if not d.any() or abs(slope) <= 1e-15 * (1.0 + abs(phi0)):
            return _Trial(1.0, d, 1.0)
        slope = min(slope, 0.0)   # not a descent direction for this ρ: ask only for simple decrease
        factor = self.config["growth"]
        growth = np.inf if factor <= 0 else \
            factor * max(ev.objective, OBJECTIVE_FLOOR, _l1(c_eq, c_ge))

        def ok(mv, alpha: float) -> tuple[bool, float]:
            pred = predicted(alpha)
            actual = phi0 - merit(mv)
            if mv.objective > growth or not np.isfinite(actual):
                return False, 0.0
            return actual >= -ETA * alpha * slope, actual / pred if pred > 0 else 1.0

        # ``speculate``: the trial point is evaluated whole (values and Jacobians) instead of
        # for its merit alone; when the step passes, that is the next iterate's evaluation.
        if speculate and hasattr(evaluator, "expect_hessian"):
            # Ahead of its test the point's violation is unknown: expect the exact Hessian
            # wherever the SQP may use one (a step that passes mostly lands near feasibility).
            evaluator.expect_hessian("exact" in self._modes(0.0, 0))
        trial = (evaluator.evaluate if speculate else evaluator.merit_values)(ev.s + d)
        good, ratio = ok(trial, 1.0)
        if good:
            return _Trial(1.0, d, ratio, trial, whole=speculate, first=True)
        if sub.qp.elastic is None and tau == 1.0:
            corrected = self._second_order_correction(la, ev, lin, sub, d, trial)
            if corrected is not None:
                values = evaluator.merit_values(ev.s + corrected)
                good, ratio = ok(values, 1.0)
                if good:
                    return _Trial(1.0, corrected, ratio, values)
        alpha = 0.5
        while backtrack and alpha >= MIN_STEP:
            check_stop()
            values = evaluator.merit_values(ev.s + alpha * d)
            good, ratio = ok(values, alpha)
            if good:
                return _Trial(alpha, d, ratio, values)
            alpha *= 0.5
        return _Trial(0.0, d)

    @staticmethod
    def _descent_weight(la, ev, lin: _Linearization, sub: _Subproblem) -> float:
        """The least merit weight for which a hard QP's step descends the ℓ1 merit by at least
        half the model's decrease (Nocedal & Wright, Numerical Optimization, (18.36)):
        (∇Rᵀd + ½ max(dᵀHd, 0)) / (½ ‖c‖₁).

        The multipliers bound it when the model is convex along d; where it is convex only on
        the null space of the binding rows (_convexify), a step that restores feasibility can
        climb the objective, and the merit must weigh the violation it removes enough for that."""
        viol = _l1(ev.c_eq[lin.eq_rows], ev.c_ge[lin.ge_rows])
        if viol <= 0.0:
            return 0.0
        d = la.vector(sub.d)
        rise = float(ev.gradient @ sub.d) + 0.5 * max(la.dot(d, la.matvec(sub.H, d)), 0.0)
        return max(rise, 0.0) / (0.5 * viol)

    @staticmethod
    def _newton(la, ev, lin: _Linearization, sub: _Subproblem):
        """The Newton step of the KKT residual test (termination.kkt_residual) at the point this
        step reached, solved with this step's own model: the system its QP factorized where
        there is one (equality rows only: one more back-substitution), else [[H, Aᵀ], [A, -ε]]
        over the rows that bound (one more factorization, as the second-order correction's).
        Deuflhard's simplified Newton correction: the derivative of the last step, the residual
        of the new point. None (no test this step) when that system is singular."""
        n = ev.s.size
        ge_rows = np.flatnonzero(sub.working)
        if ge_rows.size == 0 and sub.qp.system is not None:
            system, m = sub.qp.system, lin.eq_rows.size
        else:
            A = la.stack_rows([lin.Ae, la.rows(la.jacobian(ev, "ge"), ge_rows)])
            m = lin.eq_rows.size + ge_rows.size
            try:
                system = la.kkt(sub.H, A, KKT_EPS)
            except SingularSystem:
                return lambda r: None

        def solve(r: np.ndarray):
            try:
                return la.numpy(system.solve(la.concat([la.vector(-r), la.zeros(m)])))[:n]
            except SingularSystem:
                return None
        return solve

    @staticmethod
    def _second_order_correction(la, ev, lin: _Linearization, sub: _Subproblem, d, trial):
        """The minimum-change step that fixes the binding rows' values at the trial point."""
        ge_rows = np.flatnonzero(sub.working)
        c = np.concatenate([trial.c_eq[lin.eq_rows], trial.c_ge[ge_rows]])
        if c.size == 0:
            return None
        n = d.size
        try:
            if ge_rows.size == 0 and sub.qp.system is not None:
                system = sub.qp.system   # the same matrix [[H, A_eᵀ], [A_e, -ε]], already factorized
            else:
                A = la.stack_rows([lin.Ae, la.rows(la.jacobian(ev, "ge"), ge_rows)])
                system = la.kkt(sub.H, A, KKT_EPS)
            x = system.solve(la.concat([la.zeros(n), la.vector(-c)]))
        except SingularSystem:
            return None
        correction = la.numpy(x[:n])
        return d + correction if np.all(np.isfinite(correction)) else None

    def _conflicts(self, problem, la: LinearAlgebra, ev, lin: _Linearization) -> tuple[str, ...]:
        """Constraints in conflict: the groups that carry the multipliers of the least-violation
        QP (min ½δ|d|² + Σ elastic slacks, no objective) at ``ev``, or that stay violated."""
        n = ev.s.size
        H = la.diagonal_matrix(np.full(n, 1e-8))
        try:
            qp = solve_qp(la, H, la.zeros(n), lin.Ae, lin.ce, lin.Ai, lin.ci, elastic=1.0)
            weight = {"eq": np.abs(la.numpy(qp.y)), "ge": np.abs(la.numpy(qp.z))}
        except SingularSystem:
            weight = {"eq": np.zeros(lin.eq_rows.size), "ge": np.zeros(lin.ge_rows.size)}
        violated = {"eq": np.abs(ev.c_eq[lin.eq_rows]), "ge": np.maximum(0.0, -ev.c_ge[lin.ge_rows])}
        totals: dict[str, float] = {}
        for kind, rows in (("eq", lin.eq_rows), ("ge", lin.ge_rows)):
            sources = problem.row_sources(kind)[rows]
            for source, w, v in zip(sources, weight[kind], violated[kind]):
                totals[source] = totals.get(source, 0.0) + float(w) + (1.0 if v > 1e-6 else 0.0)
        top = max(totals.values(), default=0.0)
        return tuple(name for name, total in totals.items() if top > 0 and total >= CONFLICT_FRACTION * top)


def _l1(c_eq: np.ndarray, c_ge: np.ndarray) -> float:
    """The ℓ1 violation of equality values ``c_eq`` and inequality values ``c_ge`` (>= 0 holds)."""
    return float(np.abs(c_eq).sum() + np.maximum(0.0, -c_ge).sum())


def _no_progress(ev, new_ev, lin: _Linearization, sub: _Subproblem) -> bool:
    """Whether an elastic step lowered the ℓ1 violation neither to first order (its rows'
    linearized violation is the current one, to STATIONARY_VIOLATION: a stationary point of the
    violation) nor in fact (at the point it reached). That tells as much as no step at all, and
    the step need not be small: where rows contradict each other (x = 1 and x = 0 at one
    instant) every point between them violates them as much, and the steps wandered there for
    the whole iteration budget. (Where a row's gradient merely vanishes, x² = 1 at x = 0, a
    step the objective makes leaves that point and lowers the violation in fact.)"""
    now = _l1(ev.c_eq[lin.eq_rows], ev.c_ge[lin.ge_rows])
    reached = _l1(new_ev.c_eq[new_ev.active_eq], new_ev.c_ge[new_ev.active_ge])
    return min(_l1(sub.lin_eq, sub.lin_ge), reached) >= (1.0 - STATIONARY_VIOLATION) * now


def _conflict_message(conflicts: tuple[str, ...], violation: float, problem=None) -> str:
    over = _over_determined(conflicts, problem)
    if over:
        return over
    if not conflicts:
        return f"the constraints cannot all be met here (violation {violation:.3g} left)"
    if len(conflicts) == 1:
        # one constraint alone: its violation is stationary here, which need not hold elsewhere
        # (x^2 = 1 from x = 0, where its gradient vanishes)
        return (f"constraint {conflicts[0]} cannot be met from here: no step lowers its violation "
                f"(least violation {violation:.3g} left) — `shake` or a keyframe may move the curves "
                "where it can be")
    names = ", ".join(conflicts[:-1]) + " and " + conflicts[-1]
    return (f"constraints {names} conflict: no motion meets them all "
            f"(least violation {violation:.3g} left)")


def _over_determined(conflicts: tuple[str, ...], problem) -> str:
    """The plain reason when the rows outnumber the unknowns: the window's equality instances
    against its free control points, or those of the constraints in conflict against the free
    control points they move (empty when neither is over-determined)."""
    counter = getattr(problem, "equality_freedom", None)
    if counter is None:
        return ""
    asks = [(None, "the window has")]
    if conflicts:
        asks.append((conflicts, f"{', '.join(conflicts)} impose{'s' if len(conflicts) == 1 else ''}"))
    for sources, who in asks:
        rows, free = counter(sources)
        if rows > free:
            return (f"{who} {rows} equality instances on only {free} free control points: more "
                    "equations than the curves have freedom to meet — `refine` the DOF they read "
                    "(more knots), or give the constraints fewer samples")
    return ""


def _newton_backoff(st: SolverState, exact_refused: bool | None) -> tuple[int, int]:
    """(refusals in a row, iterations to wait) after a step, for ``hessian=auto``. A refused exact
    step costs its QP solve and halves the step limit, and the Gauss-Newton step is taken
    anyway: on basketball.stw half the exact attempts were refused, in runs of up to 17, and they
    took half the session's factorizations (516 of 1031); since more of its working sets are
    factorized banded, 16-20 of about 60 are, and the saving depends on rounding. So from the
    second refusal in a row, Gauss-Newton steps come first, 1, 2, 4 of them (up to
    NEWTON_WAIT_MAX), before the exact one is tried again; an accepted one ends the wait. One
    refusal alone waits for nothing: acrobat's next exact step is mostly accepted, and skipping
    it cost 4 iterations there."""
    if exact_refused is None:   # not tried: Gauss-Newton by choice, or still waiting
        return st.newton_refusals, max(0, st.newton_wait - 1)
    if not exact_refused:
        return 0, 0
    refusals = st.newton_refusals + 1
    return refusals, 0 if refusals < 2 else min(NEWTON_WAIT_MAX, 2 ** (refusals - 2))


def _lap(start: float) -> float:
    return (time.perf_counter() - start) * 1e3


__all__ = ["SQPBackend", "SQPInner", "SQP_OPTIONS"]
