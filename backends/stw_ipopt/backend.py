"""Solve a window problem with IPOPT through CasADi, from the problem's own numeric callbacks.

Nothing is re-derived symbolically: the objective, its gradient, the constraint values
``g(s) = [c_eq; c_ge]`` (bounds ``[0, 0]`` and ``[0, inf)``), their sparse Jacobian and the
Lagrangian Hessian all come from :meth:`WindowProblem.evaluate` and
:meth:`Evaluation.lagrangian_hessian`, wrapped as ``casadi.Callback`` functions and handed to
``nlpsol`` through its ``grad_f`` / ``jac_g`` / ``hess_lag`` options. Sparsity patterns are the
structural ones of the problem (fixed for the whole solve); the numeric matrices are scattered into
them on each call.

Sign conventions agree: stw's Lagrangian is ``R + Σ λ c`` with ``λ <= 0`` on a binding ``c >= 0``,
IPOPT's (as CasADi exposes it) is ``σ f + Σ λ g`` with ``λ_g <= 0`` on an active lower bound. So
IPOPT's Hessian is ``σ ∇²R + Σ λ ∇²c = σ·H(0, 0) + (H(λ) - H(0, 0))`` with ``H`` the problem's
``lagrangian_hessian``, and IPOPT's constraint multipliers are stw's ``lam_eq`` / ``lam_ge``.

Iterations. The stw driver calls :meth:`IpoptBackend.step` once per iteration, but IPOPT runs to
completion in one call. So the first ``step`` runs the whole solve, recording every IPOPT
iteration (its iterate through ``iteration_callback``, and ``obj``/``inf_pr``/``inf_du``/
``alpha_pr`` from the solver statistics); each ``step`` call then hands out the next recorded
iteration. Intermediate reports carry IPOPT's iterate *of that iteration* (so the curves move as
the table fills); the last one carries IPOPT's final solution and multipliers, with
``converged=True`` when the final point passes stw's own convergence tests (the same
``tol_violation`` / ``tol_kkt`` tests as every backend, stw_tui.sos.sqp.termination) and
``stalled=True`` otherwise; IPOPT's own verdict is in the message. IPOPT's ``max_iter`` is the
driver's iteration budget (``iterate N``) when that is smaller, so ``iterate 3`` runs three IPOPT
iterations, and ends as "iteration limit reached" (not stalled); a further ``iterate`` restarts
IPOPT from where it stopped. A stop from the TUI (``settings["cancelled"]``) is polled in IPOPT's
iteration callback, which then ends the solve; the run stops at the iterate IPOPT reached. The whole solve's time is charged to the first report (``ms["ipopt"]``).

Conditional rows (``when``): the masks are fixed at the start point — rows whose condition fails
there are left out of the NLP for the whole solve (IPOPT needs a fixed constraint set). A
further ``iterate`` re-evaluates the masks at its own start.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import casadi
import numpy as np
import scipy.sparse as sps

from stw_tui.sos.backend import CANCELLED, ITERATION_BUDGET, Backend, BackendOption, Capability, SolverState, StepReport
from stw_tui.sos.sqp.termination import is_converged, kkt_residual
from stw_tui.sym.errors import StwError


# --- sparsity handling ---------------------------------------------------------------------
class _Pattern:
    """A fixed CCS sparsity pattern and the scatter of a scipy matrix's values into it."""

    def __init__(self, mask: sps.sparray, shape: tuple[int, int]):
        coo = sps.coo_array(mask)
        rows, cols = np.asarray(coo.row, np.int64), np.asarray(coo.col, np.int64)
        keys = np.unique(cols * shape[0] + rows)                 # column-major order = CCS order
        self.shape, self.keys = shape, keys
        rows, cols = keys % shape[0], keys // shape[0]
        colind = np.zeros(shape[1] + 1, np.int64)
        np.add.at(colind, cols + 1, 1)
        self.sparsity = casadi.Sparsity(shape[0], shape[1], np.cumsum(colind).tolist(), rows.tolist())

    def values(self, matrix) -> np.ndarray:
        coo = sps.coo_array(matrix)
        out = np.zeros(self.keys.size)
        if coo.nnz:
            keys = np.asarray(coo.col, np.int64) * self.shape[0] + np.asarray(coo.row, np.int64)
            pos = np.searchsorted(self.keys, keys)
            pos_c = np.minimum(pos, max(self.keys.size - 1, 0))
            inside = (pos < self.keys.size) & (self.keys[pos_c] == keys) if self.keys.size else np.zeros(keys.size, bool)
            if np.any(coo.data[~inside] != 0):
                raise StwError("ipopt: a derivative fell outside its structural sparsity pattern")
            np.add.at(out, pos_c[inside], coo.data[inside])
        return out

    def dm(self, matrix) -> casadi.DM:
        return casadi.DM(self.sparsity, self.values(matrix))


def _structure(problem, eq_rows: np.ndarray, ge_rows: np.ndarray):
    """Structural patterns of the constraint Jacobian and the Hessian's upper triangle."""
    n = problem.n_free
    J = sps.vstack([problem.jacobian_structure("eq")[eq_rows], problem.jacobian_structure("ge")[ge_rows],
                    sps.csr_array((0, n))]).tocsr()
    return J, sps.triu(problem.hessian_structure(), format="csr")


# --- CasADi callbacks ----------------------------------------------------------------------
class _Cache:
    """One problem evaluation per distinct point (IPOPT asks for f, g, ∇f, J, H at the same x)."""

    def __init__(self, problem):
        self.problem = problem
        self.key: bytes | None = None
        self.ev = None
        self.h0 = None
        self.count = 0

    def at(self, x) -> object:
        s = np.asarray(x, float).ravel()
        key = s.tobytes()
        if key != self.key:
            self.key, self.ev, self.h0 = key, self.problem.evaluate(s), None
            self.count += 1
        return self.ev

    def hessian0(self, x):
        ev = self.at(x)
        if self.h0 is None:
            self.h0 = ev.lagrangian_hessian(np.zeros(ev.c_eq.size), np.zeros(ev.c_ge.size))
        return self.h0


class _Fn(casadi.Callback):
    """A casadi.Callback around a Python function of dense/sparse numpy values."""

    def __init__(self, name: str, sp_in: list, sp_out: list, fn, jacobian=None):
        casadi.Callback.__init__(self)
        self._sp_in, self._sp_out, self._fn = sp_in, sp_out, fn
        self._jacobian = jacobian  # (sparsity of d out0 / d in0, fn(x, p, out) -> [jac_x, jac_p])
        self._jac_fn = None
        self.construct(name, {"enable_fd": False})

    def has_jacobian(self):
        return self._jacobian is not None

    def get_jacobian(self, name, inames, onames, opts):
        sp_jac, fn = self._jacobian
        n_out = self._sp_out[0].size1()
        self._jac_fn = _Fn(name, self._sp_in + [self._sp_out[0]],
                           [sp_jac, casadi.Sparsity(n_out, self._sp_in[1].size1())], fn)
        return self._jac_fn

    def get_n_in(self):
        return len(self._sp_in)

    def get_n_out(self):
        return len(self._sp_out)

    def get_sparsity_in(self, i):
        return self._sp_in[i]

    def get_sparsity_out(self, i):
        return self._sp_out[i]

    def _numeric(self, args):
        return self._fn(*args)

    # casadi.Callback's hook for numeric evaluation has this name; it runs our callbacks on
    # numbers and never evaluates text.
    eval = _numeric


@dataclass
class _Record:
    obj: float
    inf_pr: float
    inf_du: float
    alpha: float
    x: np.ndarray


@dataclass
class _Inner:
    state: SolverState
    settings: dict
    eq_rows: np.ndarray
    ge_rows: np.ndarray
    records: list = field(default_factory=list)
    solved: bool = False
    success: bool = False
    message: str = ""
    seconds: float = 0.0
    evaluations: int = 0
    next: int = 0
    final: SolverState | None = None
    budget_ended: bool = False      # IPOPT stopped at the driver's budget, not its own verdict
    user_stopped: bool = False      # ... or because the user asked to stop


class IpoptBackend(Backend):
    """Interior-point NLP solve (IPOPT via CasADi) over the problem's numeric derivatives."""

    name = "ipopt"
    options = (
        BackendOption("tol", float, 1e-8, "IPOPT's overall convergence tolerance", minimum=0.0, exclusive=True),
        BackendOption("max_iter", int, 500, "IPOPT's iteration limit", minimum=1),
        BackendOption("print_level", int, 0, "IPOPT's output verbosity (0: silent; higher "
                      "levels write over the TUI)", minimum=0),
        BackendOption("hessian", str, "exact", "exact (the problem's Lagrangian Hessian) or "
                      "limited_memory (L-BFGS; IPOPT's limited-memory mode)", ("exact", "limited_memory")),
    )
    capabilities = frozenset({Capability.INEQUALITIES, Capability.CONDITIONAL, Capability.WEIGHTS})

    def init(self, problem, state: SolverState, settings: dict[str, float]) -> _Inner:
        ev = problem.evaluate(np.asarray(state.s, float))
        return _Inner(state=state, settings=dict(settings),
                      eq_rows=np.flatnonzero(ev.active_eq), ge_rows=np.flatnonzero(ev.active_ge))

    def state(self, inner: _Inner) -> SolverState:
        return inner.state

    # --- one "iteration": hand out the next recorded IPOPT iteration ------------------------
    def step(self, problem, inner: _Inner, iteration: int) -> tuple[_Inner, StepReport]:
        ms = {}
        if not inner.solved:
            self._solve(problem, inner)
            ms["ipopt"] = inner.seconds * 1e3
        k = inner.next
        inner.next += 1
        last = inner.next >= len(inner.records)
        rec = inner.records[min(k, len(inner.records) - 1)]
        if last:
            state = inner.final
        else:
            state = replace(inner.state, s=rec.x.copy())
        inner.state = state
        if not last:
            merit = problem.merit_values(state.s)
            report = StepReport(iteration=iteration, objective=float(merit.objective),
                                max_violation=problem.max_violation(merit), kkt_residual=float(rec.inf_du),
                                step_length=float(rec.alpha), linear_iterations=0,
                                active=int(np.count_nonzero((merit.c_ge <= 1e-8) & merit.active_ge)), ms=ms)
            return inner, report
        # The last report: converged by the same tests as every other backend (stw_tui.sos.sqp.termination).
        ev = problem.evaluate(state.s)
        violation = problem.max_violation(ev)
        kkt = kkt_residual(ev, state.lam_eq, state.lam_ge)
        converged = is_converged(violation, kkt, inner.settings)
        report = StepReport(iteration=iteration, objective=float(ev.objective), max_violation=violation,
                            kkt_residual=kkt, step_length=float(rec.alpha), linear_iterations=0,
                            active=int(np.count_nonzero(state.lam_ge < 0)), ms=ms,
                            converged=converged, stalled=not (converged or inner.budget_ended or inner.user_stopped),
                            message=f"IPOPT: {inner.message} ({len(inner.records)} iterations, "
                                    f"{inner.evaluations} evaluations)")
        return inner, report

    def _solve(self, problem, inner: _Inner) -> None:
        t0 = time.perf_counter()
        n = problem.n_free
        eq_rows, ge_rows = inner.eq_rows, inner.ge_rows
        m_eq, m_ge = eq_rows.size, ge_rows.size
        m = m_eq + m_ge
        J_mask, H_mask = _structure(problem, eq_rows, ge_rows)
        J_pat, H_pat = _Pattern(J_mask, (m, n)), _Pattern(H_mask, (n, n))
        cache = _Cache(problem)
        dense = casadi.Sparsity.dense
        full_eq, full_ge = problem.row_counts["eq"], problem.row_counts["ge"]

        def g_of(ev):
            return np.concatenate([ev.c_eq[eq_rows], ev.c_ge[ge_rows]])

        def jac_of(ev):
            return sps.vstack([sps.csr_array(ev.J_eq[eq_rows]), sps.csr_array(ev.J_ge[ge_rows]),
                               sps.csr_array((0, n))])

        def f(x, p):
            return [cache.at(x).objective]

        def g(x, p):
            return [g_of(cache.at(x))]

        def grad_f(x, p):
            ev = cache.at(x)
            return [ev.objective, np.asarray(ev.gradient, float)]

        def jac_g(x, p):
            ev = cache.at(x)
            return [g_of(ev), J_pat.dm(jac_of(ev))]

        def hess_lag(x, p, lam_f, lam_g):
            ev = cache.at(x)
            sigma = float(lam_f)
            lg = np.asarray(lam_g, float).ravel()
            lam_eq, lam_ge = np.zeros(full_eq), np.zeros(full_ge)
            lam_eq[eq_rows], lam_ge[ge_rows] = lg[:m_eq], lg[m_eq:]
            h0 = cache.hessian0(x)
            H = ev.lagrangian_hessian(lam_eq, lam_ge) + (sigma - 1.0) * h0
            return [H_pat.dm(sps.triu(H))]

        sx, sp0 = dense(n, 1), casadi.Sparsity(0, 1)
        keep = []  # the callbacks must outlive the solver
        F = _Fn("stw_f", [sx, sp0], [dense(1, 1)], f,
                (dense(1, n), lambda x, p, out: [np.asarray(cache.at(x).gradient, float).reshape(1, n),
                                                 casadi.DM(1, 0)]))
        Gf = _Fn("stw_g", [sx, sp0], [dense(m, 1)], g,
                 (J_pat.sparsity, lambda x, p, out: [J_pat.dm(jac_of(cache.at(x))), casadi.DM(m, 0)]))
        GF = _Fn("stw_grad_f", [sx, sp0], [dense(1, 1), sx], grad_f)
        JG = _Fn("stw_jac_g", [sx, sp0], [dense(m, 1), J_pat.sparsity], jac_g)
        keep += [F, Gf, GF, JG]

        records_x: list[np.ndarray] = []

        cancelled = inner.settings.get(CANCELLED) or (lambda: False)

        def on_iteration(x, f_, g_, lam_x, lam_g, lam_p):
            records_x.append(np.asarray(x, float).ravel().copy())
            return [1 if cancelled() else 0]     # nonzero: IPOPT stops (User_Requested_Stop)

        IC = _Fn("stw_iter", [sx, dense(1, 1), dense(m, 1), sx, dense(m, 1), sp0], [dense(1, 1)],
                 on_iteration)
        keep.append(IC)

        x = casadi.MX.sym("s", n)
        p = casadi.MX.sym("p", 0)
        nlp = {"x": x, "p": p, "f": F(x, p), "g": Gf(x, p)}
        budget = int(inner.settings.get(ITERATION_BUDGET, self.config["max_iter"]))
        max_iter = min(self.config["max_iter"], budget)
        ipopt_opts = {"tol": self.config["tol"], "max_iter": max_iter,
                      "constr_viol_tol": float(inner.settings["tol_violation"]) or 1e-12,
                      "print_level": self.config["print_level"], "sb": "yes"}
        opts = {"ipopt": ipopt_opts, "print_time": False, "grad_f": GF, "jac_g": JG,
                "iteration_callback": IC, "verbose_init": False,
                "calc_lam_p": False, "calc_lam_x": False, "calc_f": False, "calc_g": False}
        if self.config["hessian"] == "exact":
            HL = _Fn("stw_hess_lag", [sx, sp0, dense(1, 1), dense(m, 1)], [H_pat.sparsity], hess_lag)
            keep.append(HL)
            opts["hess_lag"] = HL
        else:
            ipopt_opts["hessian_approximation"] = "limited-memory"
        solver = casadi.nlpsol("stw_ipopt", "ipopt", nlp, opts)
        lbg = np.concatenate([np.zeros(m_eq), np.zeros(m_ge)])
        ubg = np.concatenate([np.zeros(m_eq), np.full(m_ge, np.inf)])
        st = inner.state
        lam0 = np.concatenate([st.lam_eq[eq_rows], st.lam_ge[ge_rows]]) if m else np.zeros(0)
        sol = solver(x0=np.asarray(st.s, float), lbg=lbg, ubg=ubg, lam_g0=lam0, p=np.zeros(0))
        stats = solver.stats()
        inner.success = bool(stats.get("success", False))
        inner.message = str(stats.get("return_status", ""))
        inner.budget_ended = inner.message == "Maximum_Iterations_Exceeded" and max_iter == budget
        s_final = np.asarray(sol["x"], float).ravel()
        lg = np.asarray(sol["lam_g"], float).ravel()
        lam_eq, lam_ge = np.zeros(full_eq), np.zeros(full_ge)
        lam_eq[eq_rows], lam_ge[ge_rows] = lg[:m_eq], lg[m_eq:]
        inner.final = replace(st, s=s_final, lam_eq=lam_eq, lam_ge=lam_ge, working_set=lam_ge < 0)
        its = stats.get("iterations", {}) or {}
        obj, inf_pr = list(its.get("obj", [])), list(its.get("inf_pr", []))
        inf_du, alpha = list(its.get("inf_du", [])), list(its.get("alpha_pr", []))
        count = min(len(obj), len(inf_pr), len(inf_du), len(alpha), len(records_x))
        # Entry 0 is the starting point; iterations are 1..count-1.
        inner.records = [_Record(obj[i], inf_pr[i], inf_du[i], alpha[i], records_x[i])
                         for i in range(1, count)]
        if not inner.records:
            inner.records = [_Record(float("nan"), 0.0, float(inf_du[-1]) if inf_du else 0.0,
                                     0.0, s_final)]
        inner.user_stopped = inner.message == "User_Requested_Stop"
        if inner.user_stopped:          # stopped from the TUI: hand out where it got to, at once
            inner.records = inner.records[-1:]
        inner.evaluations = cache.count
        inner.solved = True
        inner.seconds = time.perf_counter() - t0
        del keep, solver

