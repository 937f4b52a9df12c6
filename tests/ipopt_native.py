"""A hand-written CasADi/IPOPT reference for the ipopt backend (issue 51, item 3).

`native_pendulum` is `stw bench --anchors`' statement of the pendulum swing-up directly in
CasADi (stw_ipopt.anchor.pendulum_nlp), as a user of CasADi would write it: control
points as one SX vector, the basis matrices from scipy's BSpline at Gauss-Legendre nodes, the
objective ``Σ w (θ'' + g sin θ)²`` and the four boundary conditions, ``nlpsol`` with IPOPT's exact
Hessian. Nothing of stw's compiler or window is used, so it is an independent check of the
optimum, and the per-iteration time the ``ipopt`` backend is held against.

Run as a script (``python tests/ipopt_native.py [spans ...] [--session FILE ...]``) it times the
ipopt backend against this reference, runs interleaved, medians of several, and prints ms per
IPOPT iteration for both.
"""

from __future__ import annotations

import math
import statistics
import sys
import time

import numpy as np

G = 9.81
PENDULUM = """time 0 2 knots={spans}
const g = 9.81
dof th = pi*t/2
constraint start: th = 0, th' = 0 @ 0
constraint goal: th = pi, th' = 0 @ 2
objective effort: th'' + g*sin(th)
"""


def native_pendulum(spans: int, quadrature: int = 4, t1: float = 2.0):
    """(solver, lbg, ubg) of the swing-up over ``spans`` uniform knot spans on [0, t1]: `stw bench
    --anchors`' own CasADi statement of it (bench_targets.native_ipopt_nlp)."""
    from stw_ipopt.anchor import pendulum_nlp

    solver, target = pendulum_nlp(spans, quadrature, G, t1)
    return solver, target, target


def _stw_problem(text: str):
    from stw_tui.session.session import Session
    from stw_tui.sos.window import WindowProblem

    session = Session()
    session.run_text(text)
    return session, WindowProblem(session.scene)


def _time_backend(problem, settings, evaluation: str = "native", jit: bool = False) -> tuple[float, int, float, dict]:
    """(seconds, IPOPT iterations, objective, ms) of one whole ipopt-backend solve, through the
    driver (run_iterations: its thread, every report, stw's convergence test), as `iterate` runs it."""
    from stw_tui.sos.backend import SolverState, load_backend, run_iterations

    backend = load_backend("ipopt")(evaluation=evaluation, jit=jit)
    start = SolverState.start(problem)
    t0 = time.perf_counter()
    result = run_iterations(backend, problem, start, 3000, settings)
    seconds = time.perf_counter() - t0
    return seconds, len(result.reports), result.reports[-1].objective, result.reports[0].ms


def _time_native(solver, lbg, ubg, x0) -> tuple[float, int, float]:
    t0 = time.perf_counter()
    sol = solver(x0=x0, lbg=lbg, ubg=ubg)
    seconds = time.perf_counter() - t0
    return seconds, int(solver.stats()["iter_count"]), float(sol["f"])


def _per_iteration(runs) -> tuple[float, float]:
    """(median, least) ms per iteration over the runs."""
    per = [seconds / max(iterations, 1) * 1e3 for seconds, iterations, *_ in runs]
    return statistics.median(per), min(per)


def _solve_per_iteration(runs) -> float | None:
    """The median of the backend's own solve (its ``ms["ipopt"]``: build, IPOPT and its
    callbacks, not the driver's thread and reports) per iteration; None for the reference."""
    if len(runs[0]) < 4:
        return None
    return statistics.median(ms.get("ipopt", math.nan) / max(iterations, 1) for _, iterations, _, ms in runs)


def compare_pendulum(spans: int, runs: int = 21) -> str:
    """The ipopt backend (native and callback evaluation) against :func:`native_pendulum`, runs
    interleaved (the machine's drift falls on all three): a line of ms per iteration."""
    session, problem = _stw_problem(PENDULUM.format(spans=spans))
    x0 = problem.initial()
    solver, lbg, ubg = native_pendulum(spans, int(session.scene.settings["quadrature"]))
    settings = session.scene.settings
    configs = {"native": lambda: _time_backend(problem, settings),
               "callback": lambda: _time_backend(problem, settings, "callback"),
               "hand-written": lambda: _time_native(solver, lbg, ubg, x0)}
    found = {name: [] for name in configs}
    for name, run in configs.items():      # warm-ups: the kept solver, caches
        run()
    for _ in range(runs):
        for name, run in configs.items():
            found[name].append(run())
    return _line(f"pendulum {spans} spans", found, "hand-written")


def _line(label: str, found: dict, reference: str | None) -> str:
    parts = []
    ref = _per_iteration(found[reference])[0] if reference else None
    for name, runs in found.items():
        median, least = _per_iteration(runs)
        ratio = f" = {median / ref:.2f}x" if ref and name != reference else ""
        solve = _solve_per_iteration(runs)
        own = f", solve {solve:.3f}" + (f" = {solve / ref:.2f}x" if ref else "") if solve is not None else ""
        parts.append(f"{name} {median:.3f} (min {least:.3f}{own}, {runs[0][1]} it, J {runs[0][2]:.10g}){ratio}")
    return f"{label}: ms/iteration, medians: " + "; ".join(parts)


def time_session(path: str, runs: int = 7) -> str:
    """The ipopt backend on the window problem before a session's first `iterate`, native, jit
    and callback evaluation: a line of ms per iteration."""
    from stw_tui.session.bench import split_at_first_iterate

    with open(path, encoding="utf-8") as handle:
        setup, _ = split_at_first_iterate(handle.read())
    session, problem = _stw_problem(setup)
    settings = session.scene.settings
    configs = {"native": lambda: _time_backend(problem, settings),
               "jit": lambda: _time_backend(problem, settings, jit=True),
               "callback": lambda: _time_backend(problem, settings, "callback")}
    found = {name: [] for name in configs}
    for run in configs.values():
        run()
    for _ in range(runs):
        for name, run in configs.items():
            found[name].append(run())
    return _line(path, found, None)


if __name__ == "__main__":
    args = sys.argv[1:]
    sessions = [a for a in args if a.endswith(".stw")]
    spans = [int(a) for a in args if a.isdigit()] or ([] if sessions else [20, 80, 320])
    for k in spans:
        print(compare_pendulum(k), flush=True)
    for path in sessions:
        print(time_session(path), flush=True)
