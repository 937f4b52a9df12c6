"""Solve a window problem with IPOPT through CasADi.

Two ways to evaluate the problem. Natively (``evaluation=native``) it is built as CasADi
expressions from the compiled terms' sympy expressions (native.py, lowering.py): IPOPT then
evaluates the objective, the constraints and their exact first and second derivatives with
CasADi's own virtual machine (or, with ``jit=true``, machine code from the C compiler), with no
Python call per evaluation, as a hand-written CasADi problem would. The solver is built once per
window structure and live rows and kept (:data:`KEPT_SOLVERS`; the fixed control points are its
parameter), so a further `iterate` on the same window pays no build. With ``evaluation=callback``,
where a term holds something the lowering does not know (with a note in the last report), and
by default (``auto``) where the terms' second derivatives are too large for CasADi's virtual
machine to beat stw's compiled code (:data:`NATIVE_INSTRUCTIONS`: linkages' torques), the
problem's own numeric evaluations are used instead: the objective, its gradient, the constraint values ``g(s) = [c_eq; c_ge]``
(bounds ``[0, 0]`` and ``[0, inf)``), their sparse Jacobian and the Lagrangian Hessian come from
:meth:`WindowProblem.evaluate` and :meth:`Evaluation.lagrangian_hessian`, wrapped as
``casadi.Callback`` functions and handed to ``nlpsol`` through its ``grad_f`` / ``jac_g`` /
``hess_lag`` options. Sparsity patterns are the structural ones of the problem (fixed for the
whole solve); the numeric matrices are scattered into them on each call.

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
``stalled=True`` otherwise; IPOPT's own verdict is in the message. The driver's iteration budget
(``iterate N``) ends IPOPT after N iterations when it is below ``max_iter`` (the iteration
callback stops it there, so a kept solver serves every budget): ``iterate 3`` runs three IPOPT
iterations, and ends as "iteration limit reached" (not stalled; the message says
Maximum_Iterations_Exceeded); a further ``iterate`` restarts IPOPT from where it stopped. A stop
from the TUI (``settings["cancelled"]``) is polled in the same callback, which then ends the
solve; the run stops at the iterate IPOPT reached. The whole solve's time is charged to the first
report (``ms["ipopt"]``, and ``ms["build"]`` for building a solver that was not kept).

Conditional rows (``when``): the masks are fixed at the start point — rows whose condition fails
there are left out of the NLP for the whole solve (IPOPT needs a fixed constraint set). A
further ``iterate`` re-evaluates the masks at its own start.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import casadi
import numpy as np
import scipy.sparse as sps

from stw_tui.sos.backend import CANCELLED, ITERATION_BUDGET, Backend, BackendOption, Capability, SolverState, StepReport
from stw_tui.sos.sqp.termination import PROJECTION_EPS, is_converged, kkt_residual, projected_newton
from stw_tui.sym.errors import StwError

from .anchor import pendulum_nlp
from .native import NativeNLP, Unsupported, fixed_slot_values, forget_local_derivatives, instructions


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
    f: float = float("nan")         # the objective at x, and the live rows' values (equalities
    g: np.ndarray | None = None     # first), as IPOPT's iteration callback saw them


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
    build_seconds: float = 0.0
    evaluations: int | None = 0     # stw evaluations (the callback path); None: native
    note: str = ""                  # why the callback path (or no jit) was taken, if it was
    next: int = 0
    final: SolverState | None = None
    budget_ended: bool = False      # IPOPT stopped at the driver's budget, not its own verdict
    user_stopped: bool = False      # ... or because the user asked to stop


# evaluation=auto: the second-derivative instructions (native.instructions) above which stw's
# evaluations are used. CasADi's virtual machine runs about 8 ns an instruction; stw's LLVM code
# the same torques 50-100x faster, behind a fixed Python cost of 1-2 ms an iteration. Per
# iteration, native against callback (this machine, loaded): pendulum at 1000 spans (64k) 3.9
# against 7.3 ms, cartpole (74k) 2.2 against 8.0, arm throw (348k) 8.3 against 8.2, luxo (2.6M)
# 39 against 24, basketball (4.6M) about 85 against 37.
NATIVE_INSTRUCTIONS = 250_000
DENSE_NEWTON = 400   # variables + binding rows up to which the final Newton step is solved dense


def _dense_newton(ev, lam_eq: np.ndarray, lam_ge: np.ndarray):
    """termination.newton_step's system (the Lagrangian's Hessian, the live equality rows and
    the binding inequality rows, the same -PROJECTION_EPS block) solved dense, as ``newton`` for
    kkt_residual; None (newton_step itself) above DENSE_NEWTON unknowns. On a small window the
    sparse block assembly and LU took 0.8 ms, more than the rest of a 7-iteration solve's
    overhead; dense, 0.1 ms."""
    rows = [(ev.J_eq, np.flatnonzero(ev.active_eq)), (ev.J_ge, np.flatnonzero(ev.active_ge & (lam_ge < 0)))]
    m = sum(index.size for _, index in rows)
    n = ev.s.size
    if n + m > DENSE_NEWTON:
        return None

    def newton(r: np.ndarray) -> np.ndarray | None:
        H = ev.lagrangian_hessian(lam_eq * ev.active_eq, lam_ge * ev.active_ge).toarray()
        A = np.vstack([J.toarray()[index] for J, index in rows]) if m else np.zeros((0, n))
        return projected_newton(H, A, r, _dense_kkt_solve)   # as newton_step, dense

    return newton


def _dense_kkt_solve(H: np.ndarray, A: np.ndarray, g: np.ndarray) -> np.ndarray | None:
    """termination._sparse_kkt_solve's system, dense (LAPACK); None when singular."""
    k, m = H.shape[0], A.shape[0]
    K = np.zeros((k + m, k + m))
    K[:k, :k] = H
    if m:
        K[k:, :k], K[:k, k:] = A, A.T
        K[k:, k:] = -PROJECTION_EPS * np.eye(m)
    try:
        return np.linalg.solve(K, np.concatenate([g, np.zeros(m)]))[:k]
    except np.linalg.LinAlgError:
        return None


class _Watch(casadi.Callback):
    """IPOPT's iteration callback, and what it reads and writes during one solve: it records each
    iterate (``x``, and ``f`` and ``g`` there) and stops IPOPT at the iteration budget or when the
    user asks. It reads CasADi's buffers in place (``eval_buffer``): converting its six inputs to
    DM objects cost about 0.1 ms an iteration, a third of a native iteration at 20 spans."""

    def __init__(self, n: int, m: int):
        casadi.Callback.__init__(self)
        self._n, self._m = n, m
        self.start(lambda: False, None)
        self.construct("stw_iter", {})

    def start(self, cancelled, budget: int | None) -> None:
        """Ready for a solve: ``budget`` iterations at most (None: IPOPT's ``max_iter``)."""
        self.records: list[tuple[np.ndarray, float, np.ndarray]] = []
        self.cancelled, self.budget, self.budget_hit = cancelled, budget, False

    def get_n_in(self):
        return casadi.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return casadi.nlpsol_out(i)

    def get_sparsity_in(self, i):
        name = casadi.nlpsol_out(i)
        size = {"x": self._n, "lam_x": self._n, "f": 1, "g": self._m, "lam_g": self._m}.get(name, 0)
        return casadi.Sparsity.dense(size, 1)

    def get_sparsity_out(self, i):
        return casadi.Sparsity.dense(1, 1)

    def has_eval_buffer(self):
        return True

    def eval_buffer(self, arg, res):
        """Record the iterate; 1 in ``res[0]`` stops IPOPT (User_Requested_Stop)."""
        x = np.frombuffer(arg[0], dtype=np.float64).copy()
        f = float(np.frombuffer(arg[1], dtype=np.float64)[0]) if len(arg[1]) else float("nan")
        g = np.frombuffer(arg[2], dtype=np.float64).copy()
        self.records.append((x, f, g))
        stop = 0.0
        if self.budget is not None and len(self.records) > self.budget:   # entry 0: the start
            self.budget_hit, stop = True, 1.0
        elif self.cancelled():
            stop = 1.0
        np.frombuffer(res[0], dtype=np.float64)[0] = stop
        return 0


@dataclass(eq=False)
class _Solver:
    """An nlpsol and what it needs to run: its callbacks (which must outlive it), the watch its
    iteration callback reports to, and the parameter values of a problem (``params(problem)``)."""

    solver: casadi.Function
    watch: _Watch
    params: object
    keep: list
    evaluations: object = None      # () -> stw evaluations so far (the callback path)
    key: tuple | None = None
    holds: object = None            # the object whose id is in ``key`` (kept alive with it)
    fresh: bool = True              # built for this solve (False: a kept one)


KEPT_SOLVERS = 4                    # native solvers kept by structure (a session's few windows)
_KEPT: OrderedDict = OrderedDict()
_KEPT_LOCK = threading.Lock()


def _checkout(key: tuple) -> _Solver | None:
    """The kept solver of ``key``, taken out for one solve (two threads never share one)."""
    with _KEPT_LOCK:
        return _KEPT.pop(key, None)


def _check_in(built: _Solver) -> None:
    with _KEPT_LOCK:
        _KEPT[built.key] = built
        while len(_KEPT) > KEPT_SOLVERS:
            _KEPT.popitem(last=False)


def forget_solvers() -> None:
    """Drop the kept native solvers and the terms' local derivatives (the next solve builds
    its own, from the terms' expressions)."""
    with _KEPT_LOCK:
        _KEPT.clear()
    forget_local_derivatives()


def _jit_options() -> dict:
    """CasADi's jit of a Function through the system's C compiler, its temporary files (and the
    source a failed compile leaves) in the temporary directory, not the working directory.
    (nlpsol's own jit option is not used: it wrote its sources into the working directory.)"""
    folder = os.path.join(tempfile.gettempdir(), "")
    return {"jit": True, "compiler": "shell", "jit_name": "stw_ipopt_jit",
            "jit_options": {"flags": ["-O1"], "verbose": False, "directory": folder}}


class IpoptBackend(Backend):
    """Interior-point NLP solve (IPOPT via CasADi), on CasADi expressions of the problem's terms."""

    # `stw bench --anchors`' reference: the pendulum swing-up stated in CasADi apart from stw
    pendulum_reference = staticmethod(pendulum_nlp)

    name = "ipopt"
    options = (
        BackendOption("tol", float, 1e-8, "IPOPT's overall convergence tolerance", minimum=0.0, exclusive=True),
        BackendOption("max_iter", int, 500, "IPOPT's iteration limit", minimum=1),
        BackendOption("print_level", int, 0, "IPOPT's output verbosity (0: silent; higher "
                      "levels write over the TUI)", minimum=0),
        BackendOption("hessian", str, "exact", "exact (the problem's Lagrangian Hessian) or "
                      "limited_memory (L-BFGS; IPOPT's limited-memory mode)", ("exact", "limited_memory")),
        BackendOption("evaluation", str, "auto", "native (the terms as CasADi expressions, "
                      "evaluated by CasADi: no Python per evaluation), callback (stw's own compiled "
                      "evaluations, called from IPOPT), or auto: native unless the terms' second "
                      "derivatives are large (linkages' torques), where stw's compiled code is "
                      "faster than CasADi's virtual machine (native with jit)",
                      ("auto", "native", "callback")),
        BackendOption("jit", bool, False, "native only: compile the problem's functions to machine "
                      "code (CasADi's jit through the C compiler; the arm throw's build takes 10 s or "
                      "more, and its iterations then run 2.5-3x faster; kept with the solver)"),
    )
    capabilities = frozenset({Capability.INEQUALITIES, Capability.CONDITIONAL, Capability.WEIGHTS})

    def init(self, problem, state: SolverState, settings: dict[str, float]) -> _Inner:
        if all(group.condition is None for group in problem.groups):   # every row live
            eq, ge = (np.arange(problem.row_counts[kind]) for kind in ("eq", "ge"))
        else:
            ev = problem.merit_values(np.asarray(state.s, float))
            eq, ge = np.flatnonzero(ev.active_eq), np.flatnonzero(ev.active_ge)
        return _Inner(state=state, settings=dict(settings), eq_rows=eq, ge_rows=ge)

    def state(self, inner: _Inner) -> SolverState:
        return inner.state

    # --- one "iteration": hand out the next recorded IPOPT iteration ------------------------
    def step(self, problem, inner: _Inner, iteration: int) -> tuple[_Inner, StepReport]:
        ms = {}
        if not inner.solved:
            self._solve(problem, inner)
            ms["ipopt"] = inner.seconds * 1e3
            if inner.build_seconds:
                ms["build"] = inner.build_seconds * 1e3
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
            # The objective and the live rows' values at this iterate, as IPOPT's callback got
            # them (no stw evaluation per iteration): the rows of the NLP IPOPT solves.
            m_eq = inner.eq_rows.size
            c_eq, c_ge = rec.g[:m_eq], rec.g[m_eq:]
            violation = max(float(np.abs(c_eq).max(initial=0.0)), float((-c_ge).max(initial=0.0)))
            report = StepReport(iteration=iteration, objective=rec.f, max_violation=violation,
                                kkt_residual=float(rec.inf_du), step_length=float(rec.alpha),
                                linear_iterations=0, active=int(np.count_nonzero(c_ge <= 1e-8)), ms=ms)
            return inner, report
        # The last report: converged by the same tests as every other backend (stw_tui.sos.sqp.termination).
        ev = problem.evaluate(state.s)
        violation = problem.max_violation(ev)
        kkt = kkt_residual(ev, state.lam_eq, state.lam_ge, _dense_newton(ev, state.lam_eq, state.lam_ge))
        converged = is_converged(violation, kkt, inner.settings)
        how = ("native CasADi" if inner.evaluations is None
               else f"{inner.evaluations} stw evaluations")
        report = StepReport(iteration=iteration, objective=float(ev.objective), max_violation=violation,
                            kkt_residual=kkt, step_length=float(rec.alpha), linear_iterations=0,
                            active=int(np.count_nonzero(state.lam_ge < 0)), ms=ms,
                            converged=converged, stalled=not (converged or inner.budget_ended or inner.user_stopped),
                            message=f"IPOPT: {inner.message} ({len(inner.records)} iterations, {how})"
                                    + (f"; {inner.note}" if inner.note else ""))
        return inner, report

    # --- building a solver -----------------------------------------------------------------
    def _ipopt_options(self, inner: _Inner) -> dict:
        opts = {"tol": self.config["tol"], "max_iter": self.config["max_iter"],
                "constr_viol_tol": float(inner.settings["tol_violation"]) or 1e-12,
                "print_level": self.config["print_level"], "sb": "yes"}
        if self.config["hessian"] != "exact":
            opts["hessian_approximation"] = "limited-memory"
        return opts

    def _nlpsol(self, name: str, nlp: dict, inner: _Inner, watch: _Watch,
                extra: dict | None = None) -> casadi.Function:
        opts = {"ipopt": self._ipopt_options(inner), "print_time": False,
                "iteration_callback": watch, "verbose_init": False,
                "calc_lam_p": False, "calc_lam_x": False, "calc_f": False, "calc_g": False,
                **(extra or {})}
        return casadi.nlpsol(name, "ipopt", nlp, opts)

    def _native(self, problem, inner: _Inner) -> _Solver | None:
        """The kept native solver of this structure, or a new one; None where ``evaluation=auto``
        finds the problem's second derivatives too large for CasADi's virtual machine
        (:data:`NATIVE_INSTRUCTIONS`) and no jit is asked for.

        Raises:
            Unsupported: a term the lowering does not know.
        """
        key = (id(problem.Pf), inner.eq_rows.tobytes(), inner.ge_rows.tobytes(), self.config["jit"],
               tuple(sorted(self._ipopt_options(inner).items())))
        built = _checkout(key)
        if built is not None and built.holds is problem.Pf:
            built.fresh = False
            return built
        jit = self.config["jit"]
        if self.config["evaluation"] == "auto" and not jit and instructions(problem) > NATIVE_INSTRUCTIONS:
            return None
        # jit: MX, whose C code holds each term's functions once and loops over the instances
        nlp = NativeNLP(problem, inner.eq_rows, inner.ge_rows, "MX" if jit else "auto")
        watch = _Watch(problem.n_free, inner.eq_rows.size + inner.ge_rows.size)
        if jit:
            try:
                return self._native_solver(nlp, inner, watch, key, problem, True)
            except RuntimeError as exc:      # no C compiler, or it failed
                inner.note = (f"jit failed ({str(exc).strip().splitlines()[-1][:120]}); "
                              "evaluated by CasADi's virtual machine")
        return self._native_solver(nlp, inner, watch, key, problem, False)

    def _native_solver(self, nlp: NativeNLP, inner: _Inner, watch: _Watch, key: tuple, problem,
                       jit: bool) -> _Solver:
        compiled = _jit_options() if jit else None
        extra = nlp.derivative_options(compiled)
        if self.config["hessian"] != "exact":
            del extra["hess_lag"]
        problem_fn = nlp.nlp()
        if jit:    # f and g as one compiled Function (nlpsol derives nlp_f and nlp_g from it)
            problem_fn = casadi.Function("nlp", [nlp.x, nlp.p], [nlp.f, nlp.g], ["x", "p"], ["f", "g"], compiled)
        solver = self._nlpsol("stw_ipopt_native", problem_fn, inner, watch, extra)
        return _Solver(solver, watch, fixed_slot_values, [], key=key, holds=problem.Pf)

    def _callbacks(self, problem, inner: _Inner) -> _Solver:
        """A solver over the problem's own numeric evaluations (built per solve, not kept)."""
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
        F = _Fn("stw_f", [sx, sp0], [dense(1, 1)], f,
                (dense(1, n), lambda x, p, out: [np.asarray(cache.at(x).gradient, float).reshape(1, n),
                                                 casadi.DM(1, 0)]))
        Gf = _Fn("stw_g", [sx, sp0], [dense(m, 1)], g,
                 (J_pat.sparsity, lambda x, p, out: [J_pat.dm(jac_of(cache.at(x))), casadi.DM(m, 0)]))
        GF = _Fn("stw_grad_f", [sx, sp0], [dense(1, 1), sx], grad_f)
        JG = _Fn("stw_jac_g", [sx, sp0], [dense(m, 1), J_pat.sparsity], jac_g)
        keep = [F, Gf, GF, JG]
        extra = {"grad_f": GF, "jac_g": JG}
        if self.config["hessian"] == "exact":
            HL = _Fn("stw_hess_lag", [sx, sp0, dense(1, 1), dense(m, 1)], [H_pat.sparsity], hess_lag)
            keep.append(HL)
            extra["hess_lag"] = HL
        x = casadi.MX.sym("s", n)
        p = casadi.MX.sym("p", 0)
        watch = _Watch(n, m)
        solver = self._nlpsol("stw_ipopt", {"x": x, "p": p, "f": F(x, p), "g": Gf(x, p)},
                              inner, watch, extra)
        return _Solver(solver, watch, lambda problem: np.zeros(0), keep,
                       evaluations=lambda: cache.count)

    # --- solving ---------------------------------------------------------------------------
    def _solve(self, problem, inner: _Inner) -> None:
        t0 = time.perf_counter()
        built = None
        if self.config["evaluation"] != "callback":
            try:
                built = self._native(problem, inner)
            except Unsupported as exc:
                inner.note = f"solved through stw's evaluations: the CasADi lowering does not know {exc}"
        if built is None:
            built = self._callbacks(problem, inner)
        inner.build_seconds = time.perf_counter() - t0 if built.fresh else 0.0
        try:
            self._run(problem, inner, built)
        except BaseException:
            built = None            # a solver that raised is not kept
            raise
        finally:
            if built is not None and built.key is not None:
                _check_in(built)
        inner.seconds = time.perf_counter() - t0

    def _run(self, problem, inner: _Inner, built: _Solver) -> None:
        eq_rows, ge_rows = inner.eq_rows, inner.ge_rows
        m_eq, m_ge = eq_rows.size, ge_rows.size
        full_eq, full_ge = problem.row_counts["eq"], problem.row_counts["ge"]
        budget = int(inner.settings.get(ITERATION_BUDGET, self.config["max_iter"]))
        cancelled = inner.settings.get(CANCELLED) or (lambda: False)
        built.watch.start(cancelled, budget if budget < self.config["max_iter"] else None)
        lbg = np.concatenate([np.zeros(m_eq), np.zeros(m_ge)])
        ubg = np.concatenate([np.zeros(m_eq), np.full(m_ge, np.inf)])
        st = inner.state
        lam0 = np.concatenate([st.lam_eq[eq_rows], st.lam_ge[ge_rows]]) if m_eq + m_ge else np.zeros(0)
        sol = built.solver(x0=np.asarray(st.s, float), lbg=lbg, ubg=ubg, lam_g0=lam0, p=built.params(problem))
        stats = built.solver.stats()
        watch = built.watch
        inner.success = bool(stats.get("success", False))
        inner.message = str(stats.get("return_status", ""))
        budget_hit = watch.budget_hit and inner.message == "User_Requested_Stop"
        if budget_hit:
            inner.message = "Maximum_Iterations_Exceeded"
        inner.budget_ended = budget_hit or (inner.message == "Maximum_Iterations_Exceeded"
                                            and self.config["max_iter"] == budget)
        s_final = np.asarray(sol["x"], float).ravel()
        lg = np.asarray(sol["lam_g"], float).ravel()
        lam_eq, lam_ge = np.zeros(full_eq), np.zeros(full_ge)
        lam_eq[eq_rows], lam_ge[ge_rows] = lg[:m_eq], lg[m_eq:]
        inner.final = replace(st, s=s_final, lam_eq=lam_eq, lam_ge=lam_ge, working_set=lam_ge < 0)
        its = stats.get("iterations", {}) or {}
        obj, inf_pr = list(its.get("obj", [])), list(its.get("inf_pr", []))
        inf_du, alpha = list(its.get("inf_du", [])), list(its.get("alpha_pr", []))
        seen = watch.records
        count = min(len(obj), len(inf_pr), len(inf_du), len(alpha), len(seen))
        # Entry 0 is the starting point; iterations are 1..count-1.
        inner.records = [_Record(obj[i], inf_pr[i], inf_du[i], alpha[i], *seen[i])
                         for i in range(1, count)]
        if not inner.records:
            inner.records = [_Record(float("nan"), 0.0, float(inf_du[-1]) if inf_du else 0.0,
                                     0.0, s_final)]
        inner.user_stopped = inner.message == "User_Requested_Stop"
        if inner.user_stopped:          # stopped from the TUI: hand out where it got to, at once
            inner.records = inner.records[-1:]
        inner.evaluations = built.evaluations() if built.evaluations is not None else None
        inner.solved = True
        watch.start(lambda: False, None)      # let go of this solve's callable and iterates
