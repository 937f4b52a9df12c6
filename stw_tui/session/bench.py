"""`stw bench`: per-iteration cost and iterations to converge, per session, backend and linear solver.

How it measures (the same way for every configuration, so the rows can be compared):

* Each session is replayed, untimed, up to (not including) its **last** `iterate` line, with
  whatever backend the session itself names (the default otherwise). For most bundled sessions
  that is the scene before their one solve; for `arm_throw` and `cat_mouse` it is the scene
  before their last, windowed solve — the interactive case the paper is about.
* That scene is then solved by every configuration — each linear solver of the `scipy` backend
  and every other installed backend with its defaults — from a copy of the scene in a fresh
  session (no warm-started multipliers), with the session's own iteration count:
  `backend NAME OPTIONS` then `iterate N`, exactly as a user would type them.
* One untimed `iterate 1` first warms imports and the compiled-term caches, and one untimed
  solve of the whole window makes the plans a session keeps between `iterate`s (product plans,
  KKT orderings of its working sets: the arm's first timed run was 1.4x the others' without it,
  enough to move the median of its two-humped per-iteration times); then the solve is
  timed up to ``--repeat`` times (fewer once a configuration has used ``RUN_BUDGET_S`` seconds;
  the `runs` column says how many) and the medians are printed.
* "ms to converge" is the wall time of the `iterate` command (building the window problem plus
  all its iterations); per-iteration and per-phase times are the medians of the backend's own
  per-iteration reports over all timed runs. `ratio` is the time to converge divided by the same
  session's `scipy solver=direct` time measured in this run: the machines are shared and noisy,
  so only same-run ratios mean much. Nothing here asserts anything about time.

When the bundled sessions are benchmarked (no ``--sessions``), generated problems of the paper's
arm size and of ten times that size follow, with a summary of per-iteration cost against size.
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np
import scipy

from stw_tui.session.session import Session
from stw_tui.sos.backend import available_backends, load_backend
from stw_tui.sos.window import WindowProblem
from stw_tui.sym.errors import StwError, printable
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.language import classify_line

REFERENCE = ("scipy", "solver=direct")
PHASES = ("assemble", "solve", "line_search", "evaluate")
RUN_BUDGET_S = 5.0      # stop repeating a configuration once its timed runs took this long
SMALL, LARGE = (5, 24), (5, 264)   # synthetic sizes: 5 DOF x 27 and x 267 control points


@dataclass
class Measurement:
    """One configuration timed on one case: median times per iteration and phase, and the result."""

    session: str
    config: str
    free: int
    instances: int
    iterations: int
    converged: bool
    ms_per_iteration: float
    phases: dict[str, float]           # median ms of each phase the backend reports
    seconds: float
    objective: float
    violation: float
    motion: np.ndarray | None = None   # every DOF's value at 201 times over the span, concatenated
    inequalities: int = 0              # inequality instances among ``instances``
    linear_iterations: float = 0.0     # median linear-solver iterations per SQP iteration
    fallbacks: int = 0                 # iterative KKT solves replaced by a factorization (one run)
    runs: int = 1                      # timed runs behind the medians
    first_seconds: float = 0.0         # the untimed warm-up `iterate 1` (imports, term caches)


def configurations() -> list[tuple[str, str]]:
    """(backend, options) pairs: every linear solver of scipy, and the other installed backends."""
    configs = [("scipy", f"solver={s}") for s in ("direct", "minres", "cg")]
    for name in sorted(available_backends()):
        if name != "scipy":
            configs.append((name, ""))
    return configs


def _iterate_lines(text: str) -> list[tuple[int, int]]:
    """(index, N) of every `iterate N` line of a session text."""
    found = []
    for i, line in enumerate(text.splitlines()):
        words = classify_line(line).words
        if words[:1] == ("iterate",):
            found.append((i, int(words[1]) if len(words) > 1 and words[1].isdigit() else 1))
    return found


def _split(text: str, index: int, n: int) -> tuple[str, int]:
    # Keep the lines before it as they are, so replay errors name the session's own line numbers.
    return "\n".join(text.splitlines()[:index]), n


def split_at_first_iterate(text: str) -> tuple[str, int] | None:
    """The text before the first `iterate` line and that line's N (None: no `iterate`)."""
    found = _iterate_lines(text)
    return _split(text, *found[0]) if found else None


def split_at_last_iterate(text: str) -> tuple[str, int] | None:
    """The text before the last `iterate` line and that line's N (None: no `iterate`)."""
    found = _iterate_lines(text)
    return _split(text, *found[-1]) if found else None


def _fresh(setup: Session, config: str) -> Session:
    """A new session on a copy of ``setup``'s scene: no journal, no warm-start multipliers."""
    session = Session()
    session.scene = setup.scene.copy()
    session.warm = None
    session.execute(f"backend {config}")
    return session


def measure(name: str, setup: Session, n: int, backend: str, options: str, repeat: int,
            budget: float | None = None) -> Measurement:
    """Solve the scene of ``setup`` from the same start ``repeat`` times with one configuration.

    ``budget`` (seconds) ends the repetitions early once the timed runs have used it; at least
    one run is always timed. Raises StwError (SolveError) when the backend fails.
    """
    (result,) = measure_together(name, setup, [(backend, options, n)], repeat, budget)
    if isinstance(result, StwError):
        raise result
    return result


def measure_together(name: str, setup: Session, configs: list[tuple[str, str, int]], repeat: int,
                     budget: float | None = None, between: Callable[[], None] | None = None,
                     setups: list[Session] | None = None,
                     before: Callable[[], None] | None = None) -> list[Measurement | StwError]:
    """:func:`measure` of several configurations (backend, options, N) of one scene, their runs
    interleaved: round after round, one timed run of each, then ``between()`` (another solver
    timed by the caller). The machines are shared: their speed drifts by tens of percent over
    seconds, and a ratio of medians taken one after the other measured the drift as much as the
    solvers (pendulum against SLSQP: 2.5x to 4.6x across four quick runs); interleaved, both medians
    see the same drift.

    Each configuration stops after ``repeat`` runs or once its timed runs have used ``budget``
    seconds (at least one run each); the rounds go on while any configuration is running. A
    configuration whose solve fails is left out of the later rounds: its entry is the error.
    ``setups``: each configuration's own scene, where they differ (the same window in animations
    of two lengths); else every one solves ``setup``'s. ``before()``: called, untimed, before
    each timed run (forget what the run must not find kept).
    """
    labels = [f"{backend} {options}".strip() for backend, options, _ in configs]
    setups = setups or [setup] * len(configs)
    runs: list[list] = [[] for _ in configs]
    firsts: list[float] = [0.0] * len(configs)
    out: list[Measurement | StwError | None] = [None] * len(configs)
    for i, config in enumerate(labels):
        warm_start = time.perf_counter()
        try:   # not in the medians: imports, compiled-term caches
            _fresh(setups[i], config).execute("iterate 1")
        except StwError as exc:
            out[i] = exc
        firsts[i] = time.perf_counter() - warm_start
        if out[i] is None and configs[i][2] > 1:
            try:   # ... nor the plans worked out once per structure and kept (see the docstring)
                _fresh(setups[i], config).execute(f"iterate {configs[i][2]}")
            except StwError as exc:
                out[i] = exc

    def wants_more(i: int) -> bool:
        done = runs[i]
        return out[i] is None and (not done or (len(done) < max(1, repeat) and (
            budget is None or sum(r[0] for r in done) < budget)))

    while any(wants_more(i) for i in range(len(configs))):
        for i, (config, (_, _, n)) in enumerate(zip(labels, configs)):
            if not wants_more(i):
                continue
            try:
                session = _fresh(setups[i], config)
                if before is not None:
                    before()
                started = time.perf_counter()
                session.execute(f"iterate {n}")
            except StwError as exc:
                out[i] = exc
                continue
            runs[i].append((time.perf_counter() - started, session.runs[-1], session))
        if between is not None:
            between()
    problems = {id(s): WindowProblem(s.scene) for s in setups}
    return [out[i] if out[i] is not None else
            _summary(name, labels[i], problems[id(setups[i])], runs[i], firsts[i])
            for i in range(len(configs))]


def _summary(name: str, config: str, problem: WindowProblem, runs: list, first_seconds: float) -> Measurement:
    """One configuration's Measurement from its timed runs (seconds, RunResult, session)."""
    seconds = statistics.median(r[0] for r in runs)
    run, final = runs[0][1], runs[0][2]
    motion = np.concatenate([np.asarray(v["value"]) for v in final.sample(201).values()])
    every = [r for _, result, _ in runs for r in result.reports]
    reports = run.reports

    def median(values) -> float:
        values = list(values)
        return statistics.median(values) if values else float("nan")

    timed = [r for r in every if r.ms]
    if len(timed) == len(every):
        ms_per_iteration = median(r.total_ms for r in every)
    else:   # a backend that times its whole solve at once (ipopt): that time over its iterations
        ms_per_iteration = median(sum(r.total_ms for r in result.reports) / max(1, len(result.reports))
                                  for _, result, _ in runs)
    return Measurement(
        session=name, config=config, free=problem.n_free,
        instances=problem.row_counts[TermKind.EQ] + problem.row_counts[TermKind.GE],
        inequalities=problem.row_counts[TermKind.GE], iterations=len(reports), converged=run.converged,
        ms_per_iteration=ms_per_iteration,
        phases={k: median(r.ms.get(k, 0.0) for r in timed) for k in PHASES
                if any(k in r.ms for r in timed)},
        seconds=seconds, objective=reports[-1].objective if reports else float("nan"),
        violation=reports[-1].max_violation if reports else float("nan"), motion=motion,
        linear_iterations=median(r.linear_iterations for r in every),
        fallbacks=sum(r.fallbacks for r in reports),
        runs=len(runs), first_seconds=first_seconds)


def synthetic_session(dofs: int = SMALL[0], knots: int = SMALL[1], *, window: bool = False) -> str:
    """A generated problem of the paper's arm size (5 DOF, knots=24: 5 x 27 = 135 control points).

    Every DOF starts at rest at 0 and ends at rest at its own height; neighbouring DOF are coupled
    (``q1 - q2 = 0``) over overlapping half-span intervals sampled once per knot span; the effort
    ``q'' + k*sin(q)`` is nonlinear, so SQP takes a few Newton steps. With 5 DOF and knots=24 that
    is 20 boundary instances and 4 x 13 coupling instances (72). More knots scale control points
    and coupling instances together. ``window=True`` then changes ``k`` and re-solves only a window
    of about two and a half knot spans of the 24-knot problem (paper section 4: the cost of an
    iteration should follow the window, not the animation).
    """
    names = [f"q{i + 1}" for i in range(dofs)]
    lines = [f"time 0 1 knots={knots} samples={knots}", "const k = 10", f"dof {', '.join(names)}",
             "constraint start: " + ", ".join(f"{q} = 0, {q}' = 0" for q in names) + " @ 0",
             "constraint goal: " + ", ".join(f"{q} = {0.5 * (i + 1):g}, {q}' = 0"
                                             for i, q in enumerate(names)) + " @ 1"]
    for i, (a, b) in enumerate(zip(names, names[1:])):
        lo = (0.1, 0.2, 0.3, 0.15)[i % 4]
        # samples= keeps the paper's one instance a span (exact placement would take 16 here)
        lines.append(f"constraint couple_{a}_{b}: {a} - {b} = 0 on [{lo:g}, {lo + 0.5:g}] samples={knots}")
    lines.append("objective effort: " + ", ".join(f"{q}'' + k*sin({q})" for q in names))
    lines.append("iterate 30")
    if window:
        lines += ["const k = 12", "window focus [0.45, 0.55]", "iterate 30"]
    return "\n".join(lines)


def machine_facts() -> str:
    """One line: interpreter, library versions and CPUs."""
    def version(dist: str) -> str | None:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None

    libs = [f"numpy {np.__version__}", f"scipy {scipy.__version__}"]
    libs += [f"{d} {v}" for d in ("sympy", "symengine", "torch") if (v := version(d))]
    cpus = f"{os.cpu_count()} CPUs"
    if hasattr(os, "sched_getaffinity"):
        cpus += f" ({len(os.sched_getaffinity(0))} usable)"
    threads = ", ".join(f"{k}={os.environ[k]}" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                        "MKL_NUM_THREADS") if k in os.environ)
    return (f"python {platform.python_version()} ({platform.python_implementation()}), "
            + ", ".join(libs) + f"; {platform.system()} {platform.machine()}, {cpus}"
            + (f"; {threads}" if threads else ""))


HEADER = (f"{'session':<22} {'backend':<20} {'free':>5} {'inst':>5} {'ineq':>4} {'its':>5} "
          f"{'lin':>5} {'fb':>3} {'ms/it':>8} {'asm':>6} {'solve':>6} {'search':>6} {'eval':>6} "
          f"{'ms conv':>9} {'ratio':>6} {'objective':>12} {'max viol':>9} {'runs':>4}")


def format_row(m: Measurement, ref_seconds: float | None) -> str:
    """One row of the table (ratio '-' without a reference)."""
    ratio = f"{m.seconds / ref_seconds:6.2f}" if ref_seconds else f"{'-':>6}"
    phases = " ".join(f"{m.phases[k]:6.2f}" if k in m.phases else f"{'-':>6}" for k in PHASES)
    return (f"{m.session:<22} {m.config:<20} {m.free:>5} {m.instances:>5} {m.inequalities:>4} "
            f"{m.iterations:>4}{'' if m.converged else '*':1} {m.linear_iterations:>5.0f} {m.fallbacks:>3} "
            f"{m.ms_per_iteration:>8.2f} {phases} {m.seconds * 1e3:>9.1f} {ratio} "
            f"{m.objective:>12.6g} {m.violation:>9.1e} {m.runs:>4}")


@dataclass
class Case:
    """A scene ready to time: the session replayed up to its last `iterate`, and that line's N."""

    name: str          # the session's name, with `@window` when the solve is a window's
    setup: Session     # replayed up to the measured `iterate`
    n: int             # that line's N


def prepare(name: str, text: str) -> Case | str:
    """Replay ``text`` up to its last `iterate`; a string says why it cannot be benchmarked."""
    split = split_at_last_iterate(text)
    if split is None:
        return "no `iterate` line: nothing to time"
    prefix, n = split
    setup = Session()
    try:
        setup.run_text(prefix)
    except StwError as exc:
        return f"setup failed: {str(exc).splitlines()[0]}"
    window = setup.scene.active_window
    return Case(name if window == "all" else f"{name}@{window}", setup, n)


def bench_case(case: Case, configs: list[tuple[str, str]], repeat: int,
               out=None) -> list[Measurement]:
    """Measure every configuration on one case, printing each row as soon as it is known."""
    out = out or sys.stdout
    rows, ref = [], None
    for backend, options in configs:
        try:
            m = measure(case.name, case.setup, case.n, backend, options, repeat, RUN_BUDGET_S)
        except StwError as exc:
            print(f"{case.name:<22} {(backend + ' ' + options).strip():<20} failed: "
                  f"{printable(str(exc).splitlines()[0])}", file=out, flush=True)
            continue
        if (backend, options) == REFERENCE:
            ref = m.seconds
        rows.append(m)
        print(format_row(m, ref), file=out, flush=True)
    ipopt = next((m for m in rows if m.config == "ipopt"), None)
    if ipopt is not None and ipopt.seconds > 0:   # issue 5: every backend against the reference solver
        parts = ", ".join(f"{m.config} {m.seconds / ipopt.seconds:.2f}{_star(m).strip()}"
                          for m in rows if m is not ipopt)
        print(f"{'':<22} time to converge / ipopt's{_star(ipopt).strip()}: {parts}", file=out, flush=True)
    return rows


def _star(m: Measurement) -> str:
    return " " if m.converged else "*"


def scaling_lines(small: list[Measurement], large: list[Measurement],
                  window: list[Measurement]) -> list[str]:
    """Per configuration: median ms per iteration of the small, large and windowed-large problem."""
    lines = []
    by_config = {m.config: m for m in small}
    big, win = {m.config: m for m in large}, {m.config: m for m in window}
    for config, s in by_config.items():
        text = (f"  {config:<20} {s.free:>5} free {s.instances:>4} inst: "
                f"{s.ms_per_iteration:>8.2f} ms/it{_star(s)}")
        if (b := big.get(config)) is not None:
            growth = b.ms_per_iteration / s.ms_per_iteration
            text += (f" | {b.free:>5} free {b.instances:>4} inst ({b.free / s.free:4.1f}x size): "
                     f"{b.ms_per_iteration:>8.2f} ms/it{_star(b)} ({growth:5.1f}x)")
        if (w := win.get(config)) is not None:
            text += f" | its window, {w.free:>4} free: {w.ms_per_iteration:>7.2f} ms/it{_star(w)}"
        lines.append(text)
    return lines


def bundled_sessions() -> list[Path]:
    """sessions/*.stw of the working directory, else of the source tree this module is in."""
    for folder in (Path("sessions"), Path(__file__).resolve().parent.parent / "sessions"):
        found = sorted(folder.glob("*.stw"))
        if found:
            return found
    return []


def run_bench(args) -> int:
    """The per-configuration table and, for the bundled sessions, the scaling summary (`stw bench
    --sessions ...` or `--detail`; plain `stw bench` prints the targets, bench_targets.py)."""
    repeat = max(1, int(getattr(args, "repeat", 3) or 1))
    sessions = getattr(args, "sessions", None)
    synthetic = getattr(args, "synthetic", None)
    synthetic = not sessions if synthetic is None else synthetic
    print(f"stw bench — {machine_facts()}")
    configs, failed = [], {}
    for backend, options in configurations():
        if backend not in failed:
            try:
                load_backend(backend)
            except StwError as exc:
                failed[backend] = printable(str(exc).splitlines()[0])
                print(f"backend {backend} skipped: {failed[backend]}")
        if backend not in failed:
            configs.append((backend, options))
    print(f"each solve: the scene before the session's last `iterate`, from a fresh copy; medians of "
          f"up to {repeat} timed run(s) (fewer past {RUN_BUDGET_S:g} s; see `runs`)")
    print("ms conv: wall time of `iterate N` (window problem + iterations); ratio: ms conv / the "
          "same session's scipy solver=direct in this run")
    print("inst: constraint instances (rows), ineq of them inequalities (while inequality rows are "
          "live, the interior-point KKT systems are factorized whatever `solver` says)")
    print("ms/it and phases: medians of the backend's per-iteration times ('-': a phase it does not "
          "report; a backend that times its whole solve at once gets that time / its iterations)")
    print("lin: median linear-solver iterations per SQP iteration; fb: iterative KKT solves that fell "
          "back to a factorization; * = not converged in the session's N iterations\n")
    print(HEADER, flush=True)
    paths = sessions or bundled_sessions()
    sources = []
    for p in paths:
        try:
            sources.append((Path(p).stem, Path(p).read_text(encoding="utf-8")))
        except (OSError, UnicodeDecodeError) as exc:
            print(printable(f"{Path(p).stem:<22} cannot read {p}: {exc}"))
    small_name, large_name = (f"synthetic-{d}x{k}" for d, k in (SMALL, LARGE))
    if synthetic:   # the window variant is named after its window: synthetic-5x264@focus
        sources += [(small_name, synthetic_session(*SMALL)), (large_name, synthetic_session(*LARGE)),
                    (large_name, synthetic_session(*LARGE, window=True))]
    results: dict[str, list[Measurement]] = {}
    for name, text in sources:
        case = prepare(name, text)
        if isinstance(case, str):
            print(f"{name:<22} {case}", flush=True)
            continue
        results[case.name] = bench_case(case, configs, repeat)
    if synthetic:
        small, large = results.get(small_name, []), results.get(large_name, [])
        window = next((rows for key, rows in results.items() if key.startswith(large_name + "@")), [])
        print("\nper-iteration cost vs problem size (synthetic; median ms per SQP iteration, "
              "* = that solve did not converge, so its iterations differ in kind):")
        for line in scaling_lines(small, large, window):
            print(line)
    return 0
