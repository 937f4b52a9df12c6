"""SQP (Lagrange–Newton) iterations with sparse linear algebra, after Cohen 1992, 3.6.

Each step solves the QP of the Lagrangian's quadratic model over the linearized constraints —
with equality rows only, exactly the paper's system

    [[∇²L + δI + damping, Aᵀ], [A, 0]] [d; λ⁺] = [-∇R; -c]

and with inequality instances by an interior-point method whose iterations solve systems of the
same shape (see qp.py). Rows whose `when` condition fails at the current iterate are left out.
A backtracking line search on the ℓ1 merit function R + ρ·Σ violation follows, with a
second-order correction when the full step is refused (the Maratos effect of nonlinear
constraints would otherwise stall fast convergence).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sps

from stw_tui.backend import Backend, BackendOption, SolverState, StepReport
from stw_tui.errors import StwError

from .linear import SOLVERS, kkt_matrix, solve_kkt
from .qp import KKT_EPS, solve_qp

PROX_MIN, PROX_MAX = 1e-10, 1e8   # range of the adaptive proximal (Levenberg-Marquardt) term
ARMIJO = 1e-4            # sufficient-decrease fraction of the merit's directional derivative
MIN_STEP = 1e-8          # smallest line-search step before declaring a stall
ACTIVE_FRACTION = 1e-6   # an inequality whose multiplier exceeds this share of the largest binds


@dataclass
class _Inner:
    state: SolverState
    ev: object
    settings: dict


class ScipyBackend(Backend):
    """SQP with a sparse KKT solve: direct (SuperLU), MINRES, or CG on the least-squares form."""

    name = "scipy"
    options = (
        BackendOption("solver", str, "direct", "linear solver for the KKT system (with inequality "
                      "instances, the interior-point systems are always factorized)", SOLVERS),
        BackendOption("lin_tol", float, 1e-12, "relative tolerance of the iterative solvers"),
        BackendOption("lin_maxiter", int, 1000, "iteration limit of the iterative solvers"),
        BackendOption("max_step", float, 0.0, "largest change of any control point in one "
                      "iteration (0: no cap)"),
        BackendOption("hessian", str, "auto", "Hessian of the Lagrangian: exact (Newton), "
                      "gauss_newton (objective residuals only: positive semidefinite), or auto "
                      "(Gauss-Newton until nearly feasible, then exact)", ("auto", "exact", "gauss_newton")),
        BackendOption("prox", float, 1e-6, "initial proximal (Levenberg-Marquardt) weight; it adapts"),
        BackendOption("newton_switch", float, 1e-2, "max violation below which `auto` uses the "
                      "exact Hessian"),
    )
    capabilities = frozenset({"inequalities", "conditional", "damping", "weights"})

    def init(self, problem, state: SolverState, settings) -> _Inner:
        return _Inner(state=state, ev=problem.evaluate(state.s), settings=dict(settings))

    def state(self, inner: _Inner) -> SolverState:
        return inner.state

    # --- one iteration -----------------------------------------------------------------------
    def step(self, problem, inner: _Inner, iteration: int) -> tuple[_Inner, StepReport]:
        ms: dict[str, float] = {"assemble": 0.0, "solve": 0.0, "line_search": 0.0}
        self._fallbacks = 0
        st, ev, settings = inner.state, inner.ev, inner.settings
        modes = self._hessian_modes(ev, settings)
        # Adaptive proximal term (Levenberg-Marquardt): directions no term curves (a ball DOF
        # between constraint samples) would otherwise take huge steps the line search must cut.
        prox = st.regularization if st.regularization > 0 else self.config["prox"]
        # Trust-region-like: a refused full step is retried with a heavier proximal term
        # (shorter, better-modelled steps) before any backtracking; an exact step also as
        # Gauss-Newton. Last resort: backtracking, then a restoration step, the least change
        # that fixes the linearized constraints.
        attempts = [(mode, prox, True) for mode in modes] + \
            [(modes[-1], min(PROX_MAX, prox * 10.0 ** k), True) for k in range(1, 5)] + \
            [(modes[-1], prox, False), ("restore", prox, False)]
        for mode, prox, full_only in attempts:
            clock = time.perf_counter()
            if mode == "restore":
                H = sps.eye_array(ev.s.size, format="csr")
            elif mode == "gauss_newton":
                H = ev.gauss_newton() + self._damping(problem, settings, prox)
            else:
                H = ev.lagrangian_hessian(st.lam_eq * ev.active_eq, st.lam_ge * ev.active_ge) + \
                    self._damping(problem, settings, prox)
            ms["assemble"] += _lap(clock)

            clock = time.perf_counter()
            d, lam_eq_new, lam_ge_new, working, lin_its, resolve, A_rows = self._solve_qp(
                H, ev, st, restore=mode == "restore")
            ms["solve"] += _lap(clock)

            clock = time.perf_counter()
            rho = max(float(settings.get("merit", 1.0)),
                      1.5 * float(np.abs(np.concatenate([lam_eq_new, lam_ge_new])).max(initial=0.0)))
            biggest = float(np.abs(d).max(initial=0.0))
            if biggest > self.config["max_step"] > 0:  # a step-length cap: a crude trust region
                d = d * (self.config["max_step"] / biggest)
            alpha, d = self._line_search(problem, ev, d, rho, resolve, A_rows, full_only)
            ms["line_search"] += _lap(clock)
            if alpha > 0:
                break

        clock = time.perf_counter()
        stalled = alpha == 0.0
        s_new = ev.s + alpha * d
        if mode == "restore":  # its multipliers belong to a different problem: keep the old ones
            lam_eq_new, lam_ge_new = st.lam_eq, st.lam_ge
        # The QP's multipliers are the estimate at this point whatever the step length (a damped
        # update would freeze them, and the Hessian with them, while steps are short).
        lam_eq, lam_ge = lam_eq_new, lam_ge_new
        new_ev = problem.evaluate(s_new) if not stalled else ev
        ms["evaluate"] = _lap(clock)

        kkt = _kkt_residual(new_ev, lam_eq, lam_ge)
        violation = new_ev.max_violation()
        step_norm = alpha * float(np.abs(d).max(initial=0.0))
        tiny_step = step_norm <= settings["tol_step"] * (1.0 + float(np.abs(s_new).max(initial=0.0)))
        ok_violation = violation <= settings["tol_violation"]
        # A tiny step alone is no proof (a heavy proximal term makes steps tiny): it counts only
        # when the KKT residual is near its tolerance too (then rounding is what is left).
        converged = ok_violation and (kkt <= settings["tol_kkt"] or (tiny_step and kkt <= 1e2 * settings["tol_kkt"]))
        if stalled and ok_violation and kkt <= 1e3 * settings["tol_kkt"]:
            converged, stalled = True, False  # merit noise at machine precision near the optimum
        # Full steps: trust the model more; cut steps: less (bounded both ways).
        prox = max(PROX_MIN, prox / 3) if alpha == 1.0 else min(PROX_MAX, prox * 10)
        new_state = replace(st, s=s_new, lam_eq=lam_eq, lam_ge=lam_ge, working_set=working,
                            merit_weight=rho, regularization=prox)
        report = StepReport(iteration=iteration, objective=new_ev.objective, max_violation=violation,
                            kkt_residual=kkt, step_length=alpha, linear_iterations=lin_its,
                            active=int(working.sum()), ms=ms, converged=converged, stalled=stalled,
                            message=f"{self._fallbacks} iterative solve(s) fell back to a factorization"
                            if self._fallbacks else "")
        return _Inner(new_state, new_ev, settings), report

    def _hessian_modes(self, ev, settings) -> tuple[str, ...]:
        """Which Hessians to try this step. "auto": Gauss-Newton while far from feasible (the
        multipliers, and so the constraint curvature, mean little there), exact Newton near it."""
        choice = self.config["hessian"]
        if choice != "auto":
            return (choice,)
        if ev.max_violation() > self.config["newton_switch"]:
            return ("gauss_newton",)
        return ("exact", "gauss_newton")

    def _damping(self, problem, settings, prox: float) -> sps.csr_array:
        """Diagonal of the user's damping (paper 4.3) plus the proximal term."""
        damp = np.array([problem.scene.dofs[name].damp for name in problem.dof_of_free], dtype=float)
        return sps.diags_array(2.0 * damp + prox, format="csr")

    def _solve_qp(self, H, ev, st: SolverState, restore: bool = False):
        """The step's QP over equality rows whose `when` holds and all live inequality rows."""
        eq_rows, ge_rows = np.flatnonzero(ev.active_eq), np.flatnonzero(ev.active_ge)
        Ae, ce = ev.J_eq[eq_rows], ev.c_eq[eq_rows]
        Ai, ci = ev.J_ge[ge_rows], ev.c_ge[ge_rows]
        n = H.shape[0]
        reg, total_its = 0.0, 0
        qp = None
        for _attempt in range(8):  # raise the regularization until the step is a descent step
            Hr = H + reg * sps.eye_array(n) if reg else H
            try:
                qp = solve_qp(Hr, np.zeros(n) if restore else ev.gradient, Ae, ce, Ai, ci,
                              self.config["solver"], self.config["lin_tol"], self.config["lin_maxiter"],
                              y0=None if restore else st.lam_eq[eq_rows])
            except RuntimeError:  # exactly singular factor
                reg = max(10 * reg, 1e-8)
                continue
            total_its += qp.linear_iterations
            self._fallbacks += qp.fallbacks
            curvature = float(qp.d @ (Hr @ qp.d))
            if curvature >= -1e-12 * float(qp.d @ qp.d) or not np.any(qp.d):
                break
            reg = max(10 * reg, 1e-6 * max(1.0, float(np.abs(H.diagonal()).max())))
        if qp is None:
            raise StwError("the KKT system stayed singular under regularization: are two "
                           "constraints contradicting each other?")
        lam_eq = np.zeros(ev.c_eq.size)
        lam_eq[eq_rows] = qp.y
        lam_ge = np.zeros(ev.c_ge.size)
        lam_ge[ge_rows] = -qp.z          # L = R + Σλc: a binding h >= 0 has λ <= 0
        working = np.zeros(ev.c_ge.size, bool)
        if qp.z.size:
            working[ge_rows[qp.z > ACTIVE_FRACTION * max(1.0, float(qp.z.max()))]] = True
        A_rows = (eq_rows, np.flatnonzero(working))
        Hr = H + reg * sps.eye_array(n) if reg else H

        def resolve(rhs_c: np.ndarray) -> np.ndarray:
            """Minimum-change step that fixes constraint values rhs_c (second-order correction)."""
            A = sps.vstack([ev.J_eq[A_rows[0]], ev.J_ge[A_rows[1]]], format="csr")
            K = kkt_matrix(Hr, A, KKT_EPS)
            rhs = np.concatenate([np.zeros(n), rhs_c])
            sol = solve_kkt(K, rhs, self.config["solver"], self.config["lin_tol"], self.config["lin_maxiter"])
            return sol.x[:n]

        return qp.d, lam_eq, lam_ge, working, total_its, resolve, A_rows

    def _line_search(self, problem, ev, d, rho, resolve, A_rows, full_only=False):
        """Backtracking on φ = R + ρ·‖violation‖₁ with one second-order correction
        (``full_only``: try the full and corrected steps only)."""
        def merit(mv) -> float:
            eq = np.abs(mv.c_eq[mv.active_eq]).sum()
            ge = np.maximum(0.0, -mv.c_ge[mv.active_ge]).sum()
            return mv.objective + rho * (eq + ge)

        phi0 = merit(ev)
        viol1 = phi0 - ev.objective
        slope = float(ev.gradient @ d) - viol1
        if slope >= 0:  # not a descent direction for this ρ: ask only for simple decrease
            slope = 0.0
        if not np.any(d) or abs(slope) <= 1e-15 * (1.0 + abs(phi0)):
            return 1.0, d
        alpha = 1.0
        first = True
        while alpha >= MIN_STEP:
            trial = problem.merit_values(ev.s + alpha * d)
            if merit(trial) <= phi0 + ARMIJO * alpha * slope:
                return alpha, d
            if first:
                first = False
                corrected = self._second_order_correction(d, trial, resolve, A_rows)
                if corrected is not None:
                    trial2 = problem.merit_values(ev.s + corrected)
                    if merit(trial2) <= phi0 + ARMIJO * slope:
                        return 1.0, corrected
                if full_only:
                    return 0.0, d
            alpha *= 0.5
        return 0.0, d

    @staticmethod
    def _second_order_correction(d, trial, resolve, A_rows):
        eq_rows, ge_rows = A_rows
        c = np.concatenate([trial.c_eq[eq_rows], trial.c_ge[ge_rows]])
        if c.size == 0:
            return None
        correction = resolve(-c)
        return d + correction if np.all(np.isfinite(correction)) else None


def _kkt_residual(ev, lam_eq, lam_ge) -> float:
    """‖∇R + Σλ∇C‖∞ relative to max(1, ‖∇R‖∞)."""
    r = ev.gradient.copy()
    if lam_eq.size:
        r += ev.J_eq.T @ (lam_eq * ev.active_eq)
    if lam_ge.size:
        r += ev.J_ge.T @ lam_ge
    return float(np.abs(r).max(initial=0.0) / max(1.0, float(np.abs(ev.gradient).max(initial=0.0))))


def _lap(start: float) -> float:
    return (time.perf_counter() - start) * 1e3
