"""`stw bench` (no ``--sessions``): every speed target of issue 10 beside its measured figure.

Each row is one figure, its target and a verdict: ``met``, ``missed``, or why the target does not
apply (two solvers that reached different optima, a backend that is not installed, no CUDA
device). Targets that are ratios are measured against a reference timed in the same run on the
same machine; the machines are shared and noisy, so nothing here asserts anything about time.

What each figure is (medians of at least QUICK_REPEAT runs, or ``--repeat`` if more, within
FULL_BUDGET seconds per configuration, unless said otherwise; ``--quick``: up to QUICK_REPEAT
runs within QUICK_BUDGET seconds; the per-session figures up to SESSION_RUNS runs within the
same budgets). The
two sides of a ratio are timed in alternation, run after run (bench.measure_together), so that
the machine's drift falls on both:

* ``arm_throw first solve: ms/it``: scipy's median per-iteration time on the arm's first solve
  (the paper's arm problem); ``basketball``'s on its one solve.
* ``S: time/ipopt``: the time to converge of scipy over IPOPT's on the scene before session
  S's last `iterate` (bench.py's case; IPOPT may take up to IPOPT_ITERATIONS of its own
  iterations, not the session's N); it counts only where both converge to the same optimum
  (objectives within ``SAME_OPTIMUM``), else the verdict says why.
* ``S: torch/scipy per it``: the torch backend on the CPU against scipy, per iteration, same
  case; ``torch first iterate (S)``: the longest untimed warm-up `iterate 1` of the torch backend
  over the sessions, on a fresh copy of the scene (torch itself is imported before, by an
  untimed one-iteration solve of the smallest problem: the backend imports torch at its first
  solve, not when it is loaded; the warm-up pays the session's lowering and term caches, as a
  user's first `iterate` does).
* ``5k points: time/ipopt``: the same figure on the bench's synthetic problem at 5015 control
  points (bench.synthetic_session with LARGE_KNOTS), its `iterate` without adaptive refinement.
* ``pendulum: time / SLSQP``: the swing-up θ'' = u − g sin θ over 20 knot spans, stw's `iterate`
  against ``scipy.optimize.minimize(method="SLSQP")`` with an analytic gradient on the identical
  B-spline and quadrature, written directly in numpy (slsqp_solve). Counted when the objectives
  agree within 1e-4 relative. ``pendulum: time / FDDP`` (``--anchors``, extra ``anchors``):
  the same against crocoddyl's FDDP (fddp_solve), counted on the same condition;
  ``pendulum N: time / IPOPT`` (``--anchors``, extra ``ipopt``): against CasADi's own IPOPT on
  the identical B-spline at 20 and 80 spans (native_ipopt_pendulum, built once; stated by the
  ipopt plugin, stw_ipopt.anchor). Each reference
  alternates with stw's runs of its own (a solve that follows FDDP's is slowed down).
* ``window in 100 s / in 10 s``: the whole `iterate` of the same 1 s window in a 100 s and a 10 s
  animation of the same knot density, each building its window anew.
* ``cold start``: wall time of ``stw run`` on the arm's text up to its first `iterate`, followed
  by `iterate 1`, in a new process with a warm compile cache and bytecode cache (the process's
  whole life).
  ``arm: cached compile``: replaying that text and building its window problem with every
  in-memory cache emptied (kept.py: terms, expansions, bases, plans) and the disk cache warm.
* ``torch cuda / scipy per it`` at 10k control points: only where torch sees a CUDA device.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stw_tui.session import bench
from stw_tui.sos.backend import load_backend
from stw_tui.sos import kept
from stw_tui.sym import compiler
from stw_tui.session.bench import (Case, Measurement, bundled_sessions, machine_facts, measure,
                                   measure_together, prepare, split_at_first_iterate, synthetic_session)
from stw_tui.session.session import Session
from stw_tui.sos.window import WindowProblem, forget_builds
from stw_tui.sym.errors import StwError
from stw_tui.sym.kinds import TermKind

WIDTH = 80
LABEL, VALUE, TARGET = 34, 11, 9           # column widths; the verdict gets the rest
SAME_OPTIMUM = 1e-6                        # relative objective difference of "the same optimum"
ANCHOR_ACCURACY = 1e-4                     # relative objective difference of "equal accuracy"
# --quick: the sessions that converge in seconds (basketball: 4 s with scipy, 7 s with torch, 5 s
# with IPOPT); arm_overhand's solvers reach different optima, so it cannot count against IPOPT
QUICK_SESSIONS = ("acrobat", "arm_throw", "basketball", "cat_mouse", "particle_jet", "point_mass_2d")
# --quick times each configuration up to QUICK_REPEAT times, until QUICK_BUDGET seconds are used
# (at least once): a solve of a few milliseconds timed once is mostly noise, one of a second is not.
QUICK_REPEAT, QUICK_BUDGET = 9, 1.0
# The per-session figures take up to SESSION_RUNS runs of each configuration within the budget:
# a session of two cheap iterations gives two samples a run, and with 9 runs particle_jet's
# torch/scipy read 0.95x to 1.58x from run to run.
SESSION_RUNS = 40
FULL_BUDGET = 5.0           # seconds of timed runs per configuration otherwise (at least one run)
# IPOPT's iteration limit in the time-to-converge figures: a session's N counts SQP iterations,
# and IPOPT's interior-point iterations are many more and cheaper (acrobat: 476 to converge,
# where the session's N is 30); IPOPT's own default, so its time to converge is measured.
IPOPT_ITERATIONS = 3000
NOT_CONVERGED = 4            # `stw run`'s exit code for a solve that stopped short (cli/main.py)
COLD_START_RUNS = 3         # new processes timed for the cold start (after one that warms the cache)
_budget = FULL_BUDGET       # of the run in progress (run_targets)
PENDULUM = """time 0 2 knots=20
const g = 9.81
dof th
constraint start: th = 0, th' = 0 @ 0
constraint goal: th = pi, th' = 0 @ 2
objective effort: th'' + g*sin(th)       # u = th'' + g sin(th), the pendulum's torque
iterate 50"""


@dataclass
class Figure:
    """One measured figure and its target ``value <= limit``."""

    label: str
    value: float | None            # None: not measured (``note`` says why)
    unit: str                      # "ms", "s" or "x" (a same-run ratio)
    limit: float
    note: str = ""                 # the verdict when not measured or not counted
    counted: bool = True           # False: measured, but the target does not apply here

    def verdict(self) -> str:
        """``met`` or ``missed``, or the note when the figure is not measured or not counted."""
        if self.value is None or not self.counted:
            return self.note
        return "met" if self.value <= self.limit else "missed"


def _amount(value: float, unit: str) -> str:
    if unit == "x":
        return f"{value:.2f}x"
    if not unit:                                             # a count
        return f"{value:g}"
    return f"{value:.1f} ms" if unit == "ms" else f"{value:.2f} s"


def format_figure(f: Figure) -> str:
    """One row of the target table, at most WIDTH characters."""
    value = "-" if f.value is None else _amount(f.value, f.unit)
    target = "≤ " + (f"{f.limit:g}x" if f.unit == "x" else f"{f.limit:g} {f.unit}".rstrip())
    room = WIDTH - LABEL - VALUE - TARGET - 3
    return (f"{f.label[:LABEL]:<{LABEL}} {value:>{VALUE}} {target:>{TARGET}} "
            f"{f.verdict()[:room]}").rstrip()


def format_table(figures: list[Figure]) -> list[str]:
    """Header, one row per figure and the count of met targets."""
    header = f"{'figure':<{LABEL}} {'measured':>{VALUE}} {'target':>{TARGET}} verdict"
    judged = [f for f in figures if f.value is not None and f.counted]
    met = sum(f.verdict() == "met" for f in judged)
    return [header, "-" * len(header), *map(format_figure, figures),
            f"{met} of {len(judged)} judged targets met; {len(figures) - len(judged)} not judged"]


# --- the figures ---------------------------------------------------------------------------------

def _loadable(name: str) -> str | None:
    """None when backend ``name`` loads, else the first line of why not."""
    try:
        load_backend(name)
    except StwError as exc:
        return str(exc).splitlines()[0]
    return None


def _measure(case: Case, backend: str, options: str, repeat: int, n: int | None = None,
             ) -> Measurement | str:
    try:
        return measure(case.name, case.setup, n or case.n, backend, options, repeat, _budget)
    except StwError:
        return f"{backend} failed"


def _measure_together(case: Case, configs: list[tuple[str, str, int]], repeat: int,
                      between=None, setups=None, before=None) -> list[Measurement | str]:
    """bench.measure_together on ``case``, runs interleaved; a failed configuration: why."""
    results = measure_together(case.name, case.setup, configs, repeat, _budget, between, setups, before)
    return [f"{backend} failed" if isinstance(r, StwError) else r
            for (backend, _, _), r in zip(configs, results)]


def _import_torch() -> None:
    """Have the torch backend import torch, untimed: one iteration of the smallest problem. The
    backend imports torch at its first solve, not when it is loaded, and its first-iterate
    figure leaves torch's own import out (2-5 s here, whatever the session)."""
    probe = prepare("torch-probe", synthetic_session(1, 4))
    if not isinstance(probe, str):
        _measure(probe, "torch", "device=cpu", 1, 1)


def session_figures(sources: list[tuple[str, str]], repeat: int, out) -> list[Figure]:
    """Per session: scipy against IPOPT (time to converge) and torch (per iteration)."""
    figures, firsts = [], []
    missing = {b: why for b in ("ipopt", "torch") if (why := _loadable(b))}
    if "torch" not in missing:
        _import_torch()
    for name, text in sources:
        case = prepare(name, text)
        if isinstance(case, str):
            print(f"  {name}: {case}"[:WIDTH], file=out, flush=True)
            continue
        started = time.perf_counter()
        # scipy, IPOPT (up to its own iteration limit) and torch, their runs interleaved
        configs = [("scipy", "solver=direct", case.n)]
        if "ipopt" not in missing:
            configs.append(("ipopt", f"max_iter={IPOPT_ITERATIONS}", max(case.n, IPOPT_ITERATIONS)))
        if "torch" not in missing:
            configs.append(("torch", "device=cpu", case.n))
        measured = dict(zip((c[0] for c in configs),
                            _measure_together(case, configs, max(repeat, SESSION_RUNS))))
        scipy = measured["scipy"]
        if isinstance(scipy, str):
            figures.append(Figure(f"{name}: time/ipopt", None, "x", 0.5, scipy))
            continue
        if name == "basketball":
            figures.append(Figure("basketball: scipy ms/it", scipy.ms_per_iteration, "ms", 20.0))
        figures.append(_against_ipopt(f"{name}: time/ipopt", scipy, measured.get("ipopt", "ipopt missing")))
        torch = measured.get("torch", "torch missing")
        if isinstance(torch, str):
            figures.append(Figure(f"{name}: torch/scipy per it", None, "x", 1.5, torch))
        else:
            firsts.append((torch.first_seconds, name))
            figures.append(Figure(f"{name}: torch/scipy per it",
                                  torch.ms_per_iteration / scipy.ms_per_iteration, "x", 1.5))
        print(f"  {case.name}: {time.perf_counter() - started:.1f} s"[:WIDTH], file=out, flush=True)
    if firsts:
        seconds, where = max(firsts)
        figures.append(Figure(f"torch first iterate ({where})", seconds, "s", 1.0))
    elif "torch" in missing:
        figures.append(Figure("torch first iterate", None, "s", 1.0, "torch missing"))
    return figures


def _against_ipopt(label: str, scipy: Measurement, ipopt: Measurement | str) -> Figure:
    """scipy's time to converge over IPOPT's, counted where both converge to the same optimum."""
    if isinstance(ipopt, str):
        return Figure(label, None, "x", 0.5, ipopt)
    same = (scipy.converged and ipopt.converged and abs(scipy.objective - ipopt.objective)
            <= SAME_OPTIMUM * max(1.0, abs(ipopt.objective)))
    why = "other optimum" if scipy.converged and ipopt.converged else "not converged"
    return Figure(label, scipy.seconds / ipopt.seconds, "x", 0.5, why, counted=same)


LARGE_KNOTS = 1000   # the synthetic problem of the large figure: 5 DOF x 1003 control points


def large_figure(repeat: int) -> Figure:
    """scipy against IPOPT, time to converge, on the synthetic problem at 5015 control points: a
    large problem, where the KKT systems' regularization once made scipy crawl to its iteration
    limit (qp._finer). Without adaptive refinement: both solvers add the same 4 instances, but
    their re-solves end in different local optima (objectives 974.771 and 974.819); the first
    solves agree (970.182), and the figure compares the solvers on that problem."""
    label = "5k points: time/ipopt"
    if _loadable("ipopt"):
        return Figure(label, None, "x", 0.5, "ipopt missing")
    text = synthetic_session(5, LARGE_KNOTS).replace("iterate", "set adaptive off\niterate")
    case = prepare("synthetic-5k", text)
    if isinstance(case, str):
        return Figure(label, None, "x", 0.5, case)
    scipy, ipopt = _measure_together(case, [("scipy", "solver=direct", case.n),
                                            ("ipopt", f"max_iter={IPOPT_ITERATIONS}",
                                             max(case.n, IPOPT_ITERATIONS))], repeat)
    if isinstance(scipy, str):
        return Figure(label, None, "x", 0.5, scipy)
    return _against_ipopt(label, scipy, ipopt)


def arm_first_solve_figure(text: str, repeat: int) -> Figure:
    """scipy's per-iteration time on the arm's first solve (the paper's arm problem)."""
    split = split_at_first_iterate(text)
    setup = Session()
    setup.run_text(split[0])
    m = _measure(Case("arm_throw", setup, split[1]), "scipy", "solver=direct", repeat)
    if isinstance(m, str):
        return Figure("arm_throw first solve: ms/it", None, "ms", 4.0, m)
    return Figure("arm_throw first solve: ms/it", m.ms_per_iteration, "ms", 4.0)


def slsqp_solve(scene) -> tuple[float, float]:
    """(seconds, objective) of SLSQP on the pendulum swing-up, written directly in numpy.

    The naive choice a user would make: the same B-spline (stw's curve, its basis matrices) and
    the same quadrature rule (stw's objective instances and weights, taken untimed), the
    objective ``Σ w (θ'' + g sin θ)²`` and its analytic gradient, the four boundary conditions as
    linear equalities. Timed from building the basis matrices to SLSQP's answer.
    """
    from scipy.optimize import minimize

    group = next(g for g in WindowProblem(scene).groups if g.kind == TermKind.OBJ)
    times, w, g = group.times, group.weights, float(scene.constants["g"])
    started = time.perf_counter()
    curve = scene.dofs["th"].curve
    B0, B2 = curve.basis(times, 0).toarray(), curve.basis(times, 2).toarray()
    ends = np.array([scene.t0, scene.t1])
    A = np.vstack([curve.basis(ends, 0).toarray(), curve.basis(ends, 1).toarray()])
    b = np.array([0.0, np.pi, 0.0, 0.0])        # θ(0), θ(T), θ'(0), θ'(T)

    def objective(c):
        theta = B0 @ c
        u = B2 @ c + g * np.sin(theta)
        return float(w @ (u * u))

    def gradient(c):
        theta = B0 @ c
        r = 2.0 * w * (B2 @ c + g * np.sin(theta))
        return B2.T @ r + B0.T @ (r * g * np.cos(theta))

    result = minimize(objective, np.zeros(curve.n_coef), jac=gradient, method="SLSQP",
                      constraints=[{"type": "eq", "fun": lambda c: A @ c - b, "jac": lambda c: A}],
                      options={"maxiter": 500, "ftol": 1e-12})
    return time.perf_counter() - started, float(result.fun)


def pendulum_figures(repeat: int, anchors: bool) -> list[Figure]:
    """stw against SLSQP (and, with ``anchors``, crocoddyl FDDP and CasADi's IPOPT at 20 and 80
    spans) on the pendulum swing-up."""
    case = prepare("pendulum", PENDULUM)
    scene, g = case.setup.scene, float(case.setup.scene.constants["g"])
    quadrature = int(scene.settings["quadrature"])
    references = [("pendulum", case, "SLSQP", lambda: slsqp_solve(scene.copy()))]
    if anchors:
        try:
            import crocoddyl  # noqa: F401
            references.append(("pendulum", case, "FDDP", lambda: fddp_solve(g)))
        except ImportError:
            references.append(("pendulum", case, "FDDP", "crocoddyl missing"))
        for spans in (20, 80):
            spanned = case if spans == 20 else prepare(f"pendulum {spans}", PENDULUM.replace("knots=20", f"knots={spans}"))
            try:
                solve = native_ipopt_pendulum(spans, quadrature, g)
            except ImportError:
                solve = "casadi missing"
            references.append((f"pendulum {spans}", spanned, "IPOPT", solve))
    figures = []
    for name, case, label, solve in references:
        if isinstance(solve, str):
            figures.append(Figure(f"{name}: time / {label}", None, "x", 1.0, solve))
            continue
        solve()                                # untimed: warm caches as stw's (crocoddyl's first use)
        runs = []
        # Each reference alternates with stw's runs on its own: a solve is slowed down by what
        # ran just before it (right after FDDP's 55 ms, SLSQP's next solve took 1.9x its time
        # and stw's 1.2x), and SLSQP's runs and the stw runs they are set against must not
        # follow FDDP's. (Against FDDP itself, stw's runs follow FDDP's: the harder side.)
        (stw,) = _measure_together(case, [("scipy", "solver=direct", case.n)], max(repeat, 3),
                                   lambda: runs.append(solve()))
        if isinstance(stw, str):
            figures.append(Figure(f"{name}: time / {label}", None, "x", 1.0, stw))
            continue
        seconds, objective = statistics.median(r[0] for r in runs), runs[0][1]
        same = abs(objective - stw.objective) <= ANCHOR_ACCURACY * max(1.0, abs(objective))
        figures.append(Figure(f"{name}: time / {label}", stw.seconds / seconds, "x", 1.0,
                              f"other optimum ({label} {objective:.8g}, stw {stw.objective:.8g})",
                              counted=same))
    return figures


def native_ipopt_pendulum(spans: int, quadrature: int, g: float, t1: float = 2.0):
    """A timed solve, ``() -> (seconds, objective)``, of the ipopt plugin's own statement of the
    swing-up (stw_ipopt.anchor.pendulum_nlp: CasADi and scipy's B-spline, nothing of stw's) from
    zero control points, built once (the build is not timed, as stw's compile is not).

    Raises:
        ImportError: the ipopt backend (casadi, its extra) is not installed.
    """
    try:    # casadi stays in the backends (tests/test_layering.py): the plugin states it
        reference = load_backend("ipopt").pendulum_reference
    except (StwError, AttributeError) as exc:
        raise ImportError(str(exc)) from exc
    solver, target = reference(spans, quadrature, g, t1)

    def solve() -> tuple[float, float]:
        started = time.perf_counter()
        found = solver(x0=np.zeros(spans + 3), lbg=target, ubg=target)
        return time.perf_counter() - started, float(found["f"])

    return solve


FDDP_STEPS = 200        # RK4 steps of 0.01 s: FDDP's ∫u² is then within 1e-4 of stw's 20 spans
FDDP_GOAL_WEIGHT = 1e6  # FDDP takes costs only: the end state is a heavily weighted terminal cost


def fddp_solve(g: float, span: float = 2.0) -> tuple[float, float]:
    """(seconds, ∫u² dt) of crocoddyl's FDDP on the pendulum swing-up, as its users set it up.

    A pinocchio model (one revolute joint, a unit point mass 1 m below it: torque
    u = θ'' + g sin θ with θ = 0 hanging), free forward dynamics, fully actuated, integrated by
    RK4 over FDDP_STEPS steps; running cost u², terminal cost FDDP_GOAL_WEIGHT ‖x − (π, 0)‖² / 2;
    one thread (crocoddyl's default of one per core lost 10x to thread start-up on this
    1-DOF problem). Timed from building the model to FDDP's answer; 1e-9 stopping threshold.
    """
    import crocoddyl
    import pinocchio

    started = time.perf_counter()
    model = pinocchio.Model()
    joint = model.addJoint(0, pinocchio.JointModelRY(), pinocchio.SE3.Identity(), "pendulum")
    model.appendBodyToJoint(joint, pinocchio.Inertia(1.0, np.array([0.0, 0.0, -1.0]), np.zeros((3, 3))),
                            pinocchio.SE3.Identity())
    model.gravity.linear = np.array([0.0, 0.0, -g])
    state = crocoddyl.StateMultibody(model)
    actuation = crocoddyl.ActuationModelFull(state)
    running = crocoddyl.CostModelSum(state, actuation.nu)
    running.addCost("effort", crocoddyl.CostModelResidual(
        state, crocoddyl.ResidualModelControl(state, actuation.nu)), 2.0)          # ½·2·u²
    terminal = crocoddyl.CostModelSum(state, actuation.nu)
    terminal.addCost("goal", crocoddyl.CostModelResidual(
        state, crocoddyl.ResidualModelState(state, np.array([np.pi, 0.0]), actuation.nu)),
        FDDP_GOAL_WEIGHT)
    step = span / FDDP_STEPS

    def integrated(costs, dt):
        dynamics = crocoddyl.DifferentialActionModelFreeFwdDynamics(state, actuation, costs)
        return crocoddyl.IntegratedActionModelRK(dynamics, crocoddyl.RKType.four, dt)

    problem = crocoddyl.ShootingProblem(np.zeros(2), [integrated(running, step)] * FDDP_STEPS,
                                        integrated(terminal, 0.0))
    problem.nthreads = 1
    solver = crocoddyl.SolverFDDP(problem)
    solver.th_stop = 1e-9
    solver.solve([], [], 500)
    seconds = time.perf_counter() - started
    return seconds, float(step * np.sum(np.square(np.array(solver.us))))


def window_session(span: int) -> str:
    """The same 1 s window [4.5, 5.5] in an animation of ``span`` seconds, 4 knot spans a second."""
    return "\n".join([
        f"time 0 {span} knots={4 * span}",
        "dof x, y",
        "constraint start: x = 0, x' = 0, y = 0, y' = 0 @ 0",
        f"constraint goal: x = 1, y = 2, x' = 0, y' = 0 @ {span}",
        "objective effort: x'' + sin(y), y'' + 3*sin(x)",
        "window focus [4.5, 5.5]",
        "constraint mid: x = 2, y = -1 @ 5",
        "iterate 20"])


WINDOW_RUNS = 25   # of each animation: a 12 ms solve; medians of 9 still read 0.85x to 1.15x


def window_figure(repeat: int) -> Figure:
    """The time of one 1 s window in a 100 s animation over that in a 10 s one, their runs
    interleaved (taken one after the other, the ratio read 0.94x to 1.67x in four runs), each
    `iterate` building its window: the figure is about a build's cost, which a repeated `iterate`
    of the same structure skips (WindowProblem.of)."""
    label = "1 s window: in 100 s / 10 s"
    short, long = (prepare(f"window-{span}", window_session(span)) for span in (10, 100))
    for case in (short, long):
        if isinstance(case, str):
            return Figure(label, None, "x", 1.1, case)
    configs = [("scipy", "solver=direct", short.n), ("scipy", "solver=direct", long.n)]
    measured = _measure_together(short, configs, max(repeat, WINDOW_RUNS), setups=[short.setup, long.setup],
                                 before=forget_builds)
    for m in measured:
        if isinstance(m, str):
            return Figure(label, None, "x", 1.1, m)
    return Figure(label, measured[1].seconds / measured[0].seconds, "x", 1.1)


WAYPOINTS = 200


def waypoint_session(n: int) -> str:
    """A curve through ``n`` waypoints, each a constraint with a number of its own."""
    rng = np.random.default_rng(7)
    lines = ["time 0 10 knots=100", "dof x"]
    lines += [f"constraint w{k}: x = {v:.4f} @ {t:.4f}"
              for k, (t, v) in enumerate(zip(np.linspace(0.02, 9.98, n), rng.uniform(-1, 1, n)))]
    return "\n".join(lines + ["objective smooth: x''"])


def waypoint_figure() -> Figure:
    """How many terms setting up 200 waypoints compiles afresh (no cache): the waypoints differ
    only in their number and share one compiled term, so 2 with the objective (199 when each
    compiled its own)."""
    label = f"{WAYPOINTS} waypoints: terms compiled"
    saved_dir, build = os.environ.get("STW_CACHE_DIR"), compiler._build
    built = []
    os.environ["STW_CACHE_DIR"] = "off"
    compiler._build = lambda *args: built.append(args) or build(*args)
    try:
        compiler._CACHE.clear()                              # the in-memory cache too
        session = Session()
        session.run_text(waypoint_session(WAYPOINTS))
        WindowProblem(session.scene)
    except StwError as exc:
        return Figure(label, None, "", 2.0, str(exc)[:40])
    finally:
        compiler._build = build
        if saved_dir is None:
            os.environ.pop("STW_CACHE_DIR", None)
        else:
            os.environ["STW_CACHE_DIR"] = saved_dir
    return Figure(label, float(len(built)), "", 2.0)


def cold_start_figures(text: str, repeat: int) -> list[Figure]:
    """`stw run` of the arm up to its first iteration in a new process, and its cached compile."""
    prefix = split_at_first_iterate(text)[0]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "arm_first.stw"
        path.write_text(prefix + "\niterate 1\n", encoding="utf-8")
        command = [sys.executable, "-m", "stw_tui.cli.main", "run", str(path)]
        # Warm means Python's bytecode cache too, as any install has it: with
        # PYTHONDONTWRITEBYTECODE set (some sandboxes and CI images) every start would compile
        # stw's own modules from source again (0.13 s of the arm's 1.05 s, measured).
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        runs = []
        for i in range(1 + min(max(repeat, 1), COLD_START_RUNS)):   # the first warms the disk cache
            started = time.perf_counter()
            done = subprocess.run(command, capture_output=True, text=True, env=env)
            # one iteration leaves the solve unconverged: stw run's exit code 4 (README)
            if done.returncode not in (0, NOT_CONVERGED):
                return [Figure("cold start: stw run arm, 1 it", None, "s", 1.0, "stw run failed")]
            runs.append(time.perf_counter() - started)
    cold = Figure("cold start: stw run arm, 1 it", statistics.median(runs[1:]), "s", 1.0)
    compiles = []
    for _ in range(max(repeat, 1)):
        kept.forget()                       # every in-memory cache; the disk cache stays warm
        started = time.perf_counter()
        session = Session()
        session.run_text(prefix)
        WindowProblem(session.scene)
        compiles.append(time.perf_counter() - started)
    return [cold, Figure("arm: cached compile", statistics.median(compiles), "s", 0.1)]


def gpu_figure() -> Figure:
    """torch on CUDA against scipy per iteration at 10k control points, where a device exists."""
    label = "10k points: torch cuda / scipy"
    if _loadable("torch"):
        return Figure(label, None, "x", 0.1, "torch missing")
    # Ask the plugin (the core never imports torch): one iteration of the smallest problem on cuda.
    probe = prepare("cuda-probe", synthetic_session(1, 4))
    if isinstance(probe, str) or isinstance(_measure(probe, "torch", "device=cuda", 1, 1), str):
        return Figure(label, None, "x", 0.1, "no CUDA device")
    case = prepare("synthetic-10k", synthetic_session(5, 1997))     # 5 x 2000 control points
    if isinstance(case, str):
        return Figure(label, None, "x", 0.1, case)
    scipy, cuda = (_measure(case, b, o, 1, 3) for b, o in
                   (("scipy", "solver=direct"), ("torch", "device=cuda")))
    if isinstance(scipy, str) or isinstance(cuda, str):
        return Figure(label, None, "x", 0.1, "a solve failed")
    return Figure(label, cuda.ms_per_iteration / scipy.ms_per_iteration, "x", 0.1)


def run_targets(quick: bool, anchors: bool, repeat: int, out=None) -> list[Figure]:
    """Measure every figure, print the table (WIDTH columns) and return the figures."""
    global _budget
    out = out or sys.stdout
    started = time.perf_counter()
    # Cheap solves get QUICK_REPEAT runs in either mode: a median of 3 followed the machine's
    # bursts (the pendulum's SLSQP reference read 4.5 ms and 20 ms in successive runs).
    repeat, _budget = (QUICK_REPEAT, QUICK_BUDGET) if quick else (max(repeat, QUICK_REPEAT), FULL_BUDGET)
    for line in textwrap.wrap(f"stw bench{' --quick' if quick else ''} — {machine_facts()}", WIDTH):
        print(line, file=out)
    paths = {p.stem: p for p in bundled_sessions()}
    texts = {name: p.read_text(encoding="utf-8") for name, p in paths.items()}
    names = [n for n in QUICK_SESSIONS if n in texts] if quick else sorted(texts)
    for line in textwrap.wrap(f"sessions: {', '.join(names)}", WIDTH):
        print(line, file=out, flush=True)
    figures = []
    if "arm_throw" in texts:
        figures.append(arm_first_solve_figure(texts["arm_throw"], repeat))
    figures += session_figures([(n, texts[n]) for n in names], repeat, out)
    figures.append(large_figure(repeat))
    figures += pendulum_figures(repeat, anchors)
    figures.append(window_figure(repeat))
    figures.append(waypoint_figure())
    if "arm_throw" in texts:
        figures += cold_start_figures(texts["arm_throw"], repeat)
    figures.append(gpu_figure())
    print(file=out)
    for line in format_table(figures):
        print(line, file=out)
    print(f"ratios are same-run; {time.perf_counter() - started:.0f} s in all", file=out, flush=True)
    return figures


def run_bench(args) -> int:
    """Entry point of `stw bench`: the targets; with ``--sessions`` or ``--detail``, bench.py's
    per-configuration table instead."""
    if getattr(args, "sessions", None) or getattr(args, "detail", False):
        return bench.run_bench(args)
    run_targets(bool(getattr(args, "quick", False)), bool(getattr(args, "anchors", False)),
                max(1, int(getattr(args, "repeat", 3) or 1)))
    return 0
