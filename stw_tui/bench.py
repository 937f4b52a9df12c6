"""`stw bench`: per-iteration cost and iterations to converge, per session, backend and linear solver.

Each bundled session is replayed up to its first `iterate`; that same scene is then solved by
every configuration, several times, and the medians are printed with the time to converge as a
ratio to the reference (scipy, direct) measured in the same run — the machines are shared and
noisy, so only same-run ratios mean much.
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy

from .backend import available_backends, load_backend
from .errors import StwError
from .session import Session
from .window import WindowProblem

REFERENCE = ("scipy", "solver=direct")


@dataclass
class Measurement:
    session: str
    config: str
    free: int
    instances: int
    iterations: int
    converged: bool
    ms_per_iteration: float
    phases: dict[str, float]
    seconds: float
    objective: float
    violation: float
    motion: np.ndarray | None = None   # every DOF's value at 201 times over the span, concatenated


def configurations() -> list[tuple[str, str]]:
    """(backend, options) pairs: every linear solver of scipy, and the other installed backends."""
    configs = [("scipy", f"solver={s}") for s in ("direct", "minres", "cg")]
    for name in sorted(available_backends()):
        if name != "scipy":
            configs.append((name, ""))
    return configs


def split_at_first_iterate(text: str) -> tuple[str, int] | None:
    lines = text.splitlines()
    for i, line in enumerate(lines):
        words = line.split("#", 1)[0].split()
        if words and words[0] == "iterate":
            return "\n".join(lines[:i]), int(words[1]) if len(words) > 1 else 1
    return None


def measure(name: str, setup: Session, n: int, backend: str, options: str, repeat: int) -> Measurement:
    """Solve the scene of ``setup`` from scratch ``repeat`` times with one configuration."""
    runs = []
    warm = Session()                 # untimed: imports (torch) and compiled-term caches
    warm.scene = setup.scene.copy()
    warm.execute(f"backend {backend} {options}".strip())
    warm.execute("iterate 1")
    for _ in range(repeat):
        session = Session()
        session.scene = setup.scene.copy()
        session.execute(f"backend {backend} {options}".strip())
        started = time.perf_counter()
        session.execute(f"iterate {n}")
        runs.append((time.perf_counter() - started, session.runs[-1], session))
    seconds = statistics.median(r[0] for r in runs)
    run, final = runs[0][1], runs[0][2]
    motion = np.concatenate([np.asarray(v["value"]) for v in final.sample(201).values()])
    problem = WindowProblem(setup.scene)
    reports = run.reports
    phases = {k: statistics.median(r.ms.get(k, 0.0) for r in reports) for k in reports[0].ms} if reports else {}
    return Measurement(name, f"{backend} {options}".strip(), problem.n_free,
                       problem.row_counts["eq"] + problem.row_counts["ge"], len(reports), run.converged,
                       statistics.median(r.total_ms for r in reports) if reports else 0.0, phases,
                       seconds, reports[-1].objective if reports else float("nan"),
                       reports[-1].max_violation if reports else float("nan"), motion)


def synthetic_session(dofs: int, knots: int) -> str:
    """A generated chain of point masses pulled along by springs (sizes of the paper's problems)."""
    names = [f"q{i}" for i in range(dofs)]
    lines = [f"time 0 1 knots={knots}", "const k = 10", f"dof {', '.join(names)}"]
    lines.append("constraint start: " + ", ".join(f"{q} = 0, {q}' = 0" for q in names) + " @ 0")
    lines.append("constraint goal: " + ", ".join(f"{q} = {i + 1}" for i, q in enumerate(names)) + " @ 1")
    for a, b in zip(names, names[1:]):
        lines.append(f"constraint link_{a}: {b} - {a} <= 1.2 on [0, 1]")
    lines.append("objective effort: " + ", ".join(f"{q}'' + k*sin({q})" for q in names))
    lines.append("iterate 30")
    return "\n".join(lines)


def _row(m: Measurement, ref_seconds: float | None) -> str:
    ratio = f"{m.seconds / ref_seconds:6.2f}" if ref_seconds else "     -"
    phases = " ".join(f"{m.phases.get(k, 0.0):6.2f}" for k in ("assemble", "solve", "line_search", "evaluate"))
    return (f"{m.session:<16} {m.config:<20} {m.free:>5} {m.instances:>5} {m.iterations:>4}"
            f"{'' if m.converged else '*':1} {m.ms_per_iteration:>8.2f} {phases} {m.seconds * 1e3:>9.1f}"
            f" {ratio} {m.objective:>12.6g} {m.violation:>9.1e}")


HEADER = (f"{'session':<16} {'backend':<20} {'free':>5} {'inst':>5} {'its':>5} {'ms/it':>8} "
          f"{'asm':>6} {'solve':>6} {'search':>6} {'eval':>6} {'ms total':>9} {'ratio':>6} "
          f"{'objective':>12} {'max viol':>9}")


def run_bench(args) -> int:
    """Entry point of `stw bench`; prints the tables."""
    print(f"stw bench — python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"{os.cpu_count()} CPUs; medians of {args.repeat} runs; * = not converged")
    print("ratio: time to converge / the same session's scipy direct time, measured in this run\n")
    paths = args.sessions or sorted(Path("sessions").glob("*.stw"))
    sources = [(Path(p).stem, Path(p).read_text(encoding="utf-8")) for p in paths]
    sources += [("synthetic-5x24", synthetic_session(5, 24)), ("synthetic-50x60", synthetic_session(50, 60))]
    print(HEADER, flush=True)
    for name, text in sources:
        split = split_at_first_iterate(text)
        if split is None:
            continue
        prefix, n = split
        setup = Session()
        try:
            setup.run_text(prefix)
        except StwError as exc:
            print(f"{name:<16} setup failed: {exc}")
            continue
        ref = None
        for backend, options in configurations():
            if name.startswith("synthetic-50") and options in ("solver=minres", "solver=cg"):
                continue   # unpreconditioned Krylov solves take minutes at this size
            try:
                load_backend(backend)
                m = measure(name, setup, n, backend, options, args.repeat)
            except StwError as exc:
                print(f"{name:<16} {backend + ' ' + options:<20} skipped: {str(exc).splitlines()[0]}")
                continue
            if (backend, options) == REFERENCE:
                ref = m.seconds
            print(_row(m, ref))
        sys.stdout.flush()
    return 0
